"""Lazy public names for a package ``__init__`` (PEP 562): a name's module is imported on first use."""

from __future__ import annotations

import importlib


def lazy_exports(package: str, exports: dict[str, str], namespace: dict, extra_dir=()):
    """``(__getattr__, __dir__)`` for ``package`` whose public name ``n`` lives in ``package.exports[n]``.

    The first access imports the module and caches the value in the package's ``namespace`` (its
    ``globals()``), so later accesses are ordinary attribute lookups.
    """

    def __getattr__(name: str):
        mod = exports.get(name)
        if mod is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{mod}", package), name)
        namespace[name] = value
        return value

    def __dir__():
        return sorted(set(namespace) | set(exports) | set(extra_dir))

    return __getattr__, __dir__
