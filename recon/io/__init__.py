"""Interchange with other ecosystems: y-tal HDF5 (``read_ytal``/``write_ytal``) and public real-capture
layouts (:mod:`recon.io.real`). transient-mi's own EXR stack is :mod:`transient_core.stack`.

The HDF5 readers and writers are imported on first use (h5py is only needed then)."""

__all__ = ["read_ytal", "write_ytal"]

_LAZY = {"read_ytal": "ytal", "write_ytal": "ytal"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
