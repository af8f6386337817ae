"""Capture I/O: the EXR histogram stack, y-tal HDF5 (``read_ytal``/``write_ytal``) and public real-capture
layouts (:mod:`recon.io.real`).

The HDF5 readers and writers are imported on first use (h5py is only needed then)."""

from .stack import (
    FORMAT,
    FORMAT_VERSION,
    StackError,
    channel_names,
    iter_spots,
    missing_spots,
    new_manifest,
    read_manifest,
    read_spot,
    read_stack,
    spot_filename,
    spot_is_complete,
    write_manifest,
    write_spot,
    write_stack,
)

__all__ = [
    "FORMAT", "FORMAT_VERSION", "StackError", "channel_names", "iter_spots", "missing_spots",
    "new_manifest", "read_manifest", "read_spot", "read_stack", "spot_filename",
    "spot_is_complete", "write_manifest", "write_spot", "write_stack", "read_ytal", "write_ytal",
]

_LAZY = {"read_ytal": "ytal", "write_ytal": "ytal"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
