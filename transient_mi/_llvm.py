"""Find an LLVM >= 17 for drjit's LLVM backend *before* drjit is imported.

drjit 1.5 JIT-compiles the ``llvm_*`` Mitsuba variants with the system's
``libLLVM``. It needs LLVM 17 or newer; with LLVM 14/15 (what many Linux
distributions ship) it picks the old library and aborts inside LLVM's
instruction selector ("Cannot select fminimum"). drjit reads the path of the
library from the environment variable ``DRJIT_LIBLLVM_PATH`` when it is first
imported, so this module must run before ``import drjit``.

Resolution order:

1. ``DRJIT_LIBLLVM_PATH`` if the user set it (its version is checked);
2. the ``libLLVM`` shipped by the ``karellen-llvm-core`` wheel, a dependency of
   this package on Linux x86-64;
3. a system ``libLLVM-NN.so`` with NN >= 17.

Nothing here imports drjit or mitsuba.
"""

from __future__ import annotations

import ctypes
import glob
import os
import re
from importlib import metadata
from pathlib import Path

#: Oldest LLVM major version drjit 1.5 works with.
MIN_LLVM_MAJOR = 17

ENV_VAR = "DRJIT_LIBLLVM_PATH"


class LLVMNotFoundError(ImportError):
    """No usable LLVM (>= 17) for drjit's LLVM backend could be found."""


def llvm_version(path: str | os.PathLike) -> tuple[int, int, int] | None:
    """Return ``(major, minor, patch)`` of the libLLVM at ``path``.

    Uses the C API ``LLVMGetVersion`` (LLVM >= 16). Returns ``None`` when the
    library cannot be loaded or predates that function (LLVM <= 15, too old
    for drjit anyway).
    """
    try:
        lib = ctypes.CDLL(str(path), mode=getattr(os, "RTLD_LOCAL", 0))
    except OSError:
        return None
    fn = getattr(lib, "LLVMGetVersion", None)
    if fn is None:
        return None
    major, minor, patch = ctypes.c_uint(), ctypes.c_uint(), ctypes.c_uint()
    fn(ctypes.byref(major), ctypes.byref(minor), ctypes.byref(patch))
    return major.value, minor.value, patch.value


def _karellen_candidates() -> list[Path]:
    """libLLVM files installed by the ``karellen-llvm-core`` distribution."""
    try:
        dist = metadata.distribution("karellen-llvm-core")
    except metadata.PackageNotFoundError:
        return []
    found = []
    for f in dist.files or ():
        name = Path(str(f)).name
        if re.fullmatch(r"libLLVM(-\d+)?\.so(\.\d+)*", name):
            p = Path(dist.locate_file(f)).resolve()
            if p.is_file():
                found.append(p)
    # De-duplicate symlinks that resolve to the same real file.
    return sorted(set(found))


def _system_candidates() -> list[Path]:
    pats = [
        "/usr/lib/llvm-*/lib/libLLVM*.so*",
        "/usr/lib/x86_64-linux-gnu/libLLVM-*.so*",
        "/usr/lib/aarch64-linux-gnu/libLLVM-*.so*",
        "/usr/lib64/libLLVM-*.so*",
        "/usr/local/lib/libLLVM*.so*",
        "/opt/homebrew/opt/llvm/lib/libLLVM.dylib",
        "/usr/local/opt/llvm/lib/libLLVM.dylib",
    ]
    out: list[Path] = []
    for pat in pats:
        out.extend(Path(p).resolve() for p in glob.glob(pat))
    return sorted(set(p for p in out if p.is_file()), reverse=True)


def _message(tried: list[str]) -> str:
    lines = [
        f"transient-mi: no usable LLVM (>= {MIN_LLVM_MAJOR}) found for drjit's llvm_* variants.",
    ]
    if tried:
        lines.append("Tried: " + "; ".join(tried) + ".")
    lines += [
        "Fix one of:",
        "  pip install 'karellen-llvm-core>=19.1,<20'   (ships libLLVM 19; Linux x86-64)",
        f"  export {ENV_VAR}=/path/to/libLLVM.so        (any LLVM >= {MIN_LLVM_MAJOR})",
        "  export TRANSIENT_MI_VARIANT=cuda_ad_mono      (on a machine with an NVIDIA GPU)",
    ]
    return "\n".join(lines)


def resolve_llvm(environ: dict | None = None) -> str:
    """Point ``DRJIT_LIBLLVM_PATH`` at a usable libLLVM and return its path.

    Parameters
    ----------
    environ : dict, optional
        Environment to read and update (default ``os.environ``).

    Raises
    ------
    LLVMNotFoundError
        If the user's ``DRJIT_LIBLLVM_PATH`` is too old or unloadable, or if
        no LLVM >= 17 is installed; the message says what to install or set.
    """
    env = os.environ if environ is None else environ
    user = env.get(ENV_VAR)
    if user:
        ver = llvm_version(user)
        if ver is None or ver[0] < MIN_LLVM_MAJOR:
            got = "cannot be loaded or is older than LLVM 16" if ver is None else "is LLVM %d.%d.%d" % ver
            raise LLVMNotFoundError(
                f"transient-mi: {ENV_VAR}={user} {got}; drjit needs LLVM >= {MIN_LLVM_MAJOR}.\n"
                + _message([])
            )
        return user

    tried: list[str] = []
    for cand in _karellen_candidates() + _system_candidates():
        ver = llvm_version(cand)
        tried.append(f"{cand} ({'LLVM %d.%d.%d' % ver if ver else 'too old or unloadable'})")
        if ver is not None and ver[0] >= MIN_LLVM_MAJOR:
            env[ENV_VAR] = str(cand)
            return str(cand)
    raise LLVMNotFoundError(_message(tried))
