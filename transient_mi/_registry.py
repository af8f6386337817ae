"""Discovery and registration of transient-mi's Mitsuba plug-ins.

Every module in the sub-packages ``films``, ``integrators``, ``sensors``,
``emitters`` and ``shapes`` that defines ``PLUGIN = (kind, name, class_name)``
is a plug-in (``class_name`` may also name a factory function taking the
``mi.Properties``).
Plug-in classes derive from variant-specific Mitsuba base classes
(``mi.Film`` of the active variant, ...), so on a variant change every module
of those sub-packages is dropped from ``sys.modules`` and imported afresh
(a plug-in that subclasses another, such as ``spad_film`` deriving from
``transient_film``, then imports the new base class), and registered again.
Helper modules must look variant-specific types up at call time
(``mi.Float``), never bind them at import.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import mitsuba as mi

_SUBPACKAGES = ("films", "sensors", "emitters", "integrators", "shapes")
_REGISTER = {
    "film": "register_film",
    "sensor": "register_sensor",
    "emitter": "register_emitter",
    "integrator": "register_integrator",
    "shape": "register_shape",
}
_registered: dict[str, tuple[str, str]] = {}


def _plugin_modules():
    for sub in _SUBPACKAGES:
        pkg = importlib.import_module(f"transient_mi.{sub}")
        for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
            if not info.name.startswith("_"):
                yield f"transient_mi.{sub}.{info.name}"


def register_plugins() -> dict[str, tuple[str, str]]:
    """(Re-)import the plug-in modules for the active variant and register them.

    Returns a mapping ``name -> (kind, module)``.
    """
    _registered.clear()
    prefixes = tuple(f"transient_mi.{sub}." for sub in _SUBPACKAGES)
    for name in [n for n in sys.modules if n.startswith(prefixes)]:
        del sys.modules[name]
    for modname in _plugin_modules():
        mod = importlib.import_module(modname)
        spec = getattr(mod, "PLUGIN", None)
        if spec is None:
            continue
        kind, name, clsname = spec
        cls = getattr(mod, clsname)
        getattr(mi, _REGISTER[kind])(name, lambda props, _cls=cls: _cls(props))
        _registered[name] = (kind, modname)
    return dict(_registered)


def plugin_names() -> dict[str, tuple[str, str]]:
    """Registered plug-ins: ``name -> (kind, module)``."""
    return dict(_registered)
