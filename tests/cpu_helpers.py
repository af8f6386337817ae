"""The instruction-set class of this x86-64 CPU, for byte-level records that depend on it.

LLVM (drjit's ``llvm_*`` backend) selects other instructions on an AVX-512 machine than on an AVX2-only one
(e.g. approximate reciprocal square roots), so some renders differ in their last bits between the two; a
test that pins bytes keeps one record per class (``tests/data/golden_hashes.json``, ``test_sampler_rfilter``).
"""

from __future__ import annotations


def cpu_class() -> str:
    """``"avx512"``, ``"avx2"`` or ``"other"`` (from the ``flags`` line of ``/proc/cpuinfo``)."""
    try:
        with open("/proc/cpuinfo") as f:
            flags = next((line.split(":", 1)[1].split() for line in f if line.startswith("flags")), [])
    except OSError:
        flags = []
    if "avx512f" in flags:
        return "avx512"
    if "avx2" in flags:
        return "avx2"
    return "other"
