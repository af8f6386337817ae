"""transient-mi: time-of-flight light transport on Mitsuba 3.

Importing this package

1. points drjit at an LLVM >= 17 (before drjit is imported, see
   :mod:`transient_mi._llvm`),
2. selects a Mitsuba variant (``llvm_ad_mono`` unless ``TRANSIENT_MI_VARIANT``
   says otherwise, see :mod:`transient_mi.variant`),
3. registers the plug-ins ``transient_film``, ``spad_film``,
   ``transient_path``, ``transient_nlos_path``, ``spad_array`` and
   ``pulsed_laser`` with Mitsuba, so
   they can be used from XML scenes and Python dictionaries.

Switch variants afterwards with :func:`transient_mi.set_variant`, which
re-registers the plug-ins for the new variant.
"""

from __future__ import annotations


from transient_core import __version__  # the distribution's version
from ._llvm import LLVMNotFoundError, resolve_llvm as _resolve_llvm
from .variant import DEFAULT_VARIANT, VariantError, requested_variant as _requested_variant

_VARIANT = _requested_variant()
_LLVM_ERROR: LLVMNotFoundError | None = None
try:
    LLVM_PATH: str | None = _resolve_llvm()
except LLVMNotFoundError as _e:  # only fatal if an llvm_* variant is used
    LLVM_PATH, _LLVM_ERROR = None, _e

import drjit as _dr  # noqa: E402  (after the LLVM environment is set)
import mitsuba as _mi  # noqa: E402

from ._registry import register_plugins as _register_plugins, plugin_names  # noqa: E402


def _check_llvm_backend(variant: str) -> None:
    if not variant.startswith("llvm_"):
        return
    major = _dr.detail.llvm_version()[0]
    if major >= 17:
        return
    if _LLVM_ERROR is not None:
        raise _LLVM_ERROR
    loaded = "no LLVM" if major < 0 else "LLVM %d.%d.%d" % _dr.detail.llvm_version()
    raise LLVMNotFoundError(
        f"transient-mi: drjit loaded {loaded}, but llvm_* variants need LLVM >= 17. "
        "drjit was probably imported before transient_mi, so DRJIT_LIBLLVM_PATH came too late: "
        "import transient_mi first, or export DRJIT_LIBLLVM_PATH="
        + (LLVM_PATH or "/path/to/libLLVM.so (>= 17)")
    )


#: The variant the plug-ins were last registered for.
_PLUGINS_VARIANT: str | None = None


def set_variant(name: str) -> str:
    """Select Mitsuba variant ``name`` and (re-)register the plug-ins for it.

    Raises
    ------
    VariantError
        If this Mitsuba build has no such variant.
    LLVMNotFoundError
        If an ``llvm_*`` variant is asked for and no LLVM >= 17 is loaded.
    """
    from .variant import check_variant

    global _PLUGINS_VARIANT
    check_variant(name)
    _check_llvm_backend(name)
    if _mi.variant() != name:
        _mi.set_variant(name)
    if _PLUGINS_VARIANT != name:  # the same variant again keeps its plug-in modules (no re-import)
        _register_plugins()
        _PLUGINS_VARIANT = name
    return name


def variant() -> str:
    """The active Mitsuba variant."""
    return _mi.variant()


set_variant(_VARIANT)

__all__ = [
    "LLVM_PATH",
    "LLVMNotFoundError",
    "VariantError",
    "DEFAULT_VARIANT",
    "set_variant",
    "variant",
    "plugin_names",
    "__version__",
]
