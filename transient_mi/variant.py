"""Mitsuba variant selection for transient-mi.

The default is ``llvm_ad_mono`` (CPU, JIT-compiled, one spectral channel: the
natural choice for a single-wavelength laser). Override it with the
environment variable ``TRANSIENT_MI_VARIANT`` (read when ``transient_mi`` is
first imported), the command line's ``--variant``, or :func:`set_variant`.

- ``llvm_*``: CPU; need LLVM >= 17 (see :mod:`transient_mi._llvm`).
- ``cuda_*``: NVIDIA GPU.
- ``scalar_*``: scenes load and plug-ins are constructed (to debug XML and
  plug-in parameters in a debugger); rendering needs a JIT (``llvm_*`` or
  ``cuda_*``) variant.
"""

from __future__ import annotations

import os

DEFAULT_VARIANT = "llvm_ad_mono"
ENV_VAR = "TRANSIENT_MI_VARIANT"


from transient_core.errors import UserInputError


class VariantError(UserInputError):
    """An unknown or unusable Mitsuba variant was requested."""


def requested_variant(environ: dict | None = None) -> str:
    """The variant asked for by ``TRANSIENT_MI_VARIANT``, else the default."""
    env = os.environ if environ is None else environ
    return env.get(ENV_VAR, "").strip() or DEFAULT_VARIANT


def available_variants() -> list[str]:
    import mitsuba as mi

    return list(mi.variants())


def check_variant(name: str) -> str:
    """Return ``name`` if this Mitsuba build has it, else raise VariantError."""
    avail = available_variants()
    if name not in avail:
        raise VariantError(
            f"variant={name!r} is not available in this Mitsuba build; "
            f"allowed: {', '.join(avail)}"
        )
    return name


def is_jit(name: str) -> bool:
    """True for variants that trace and JIT-compile (``llvm_*``, ``cuda_*``)."""
    return name.startswith(("llvm_", "cuda_"))
