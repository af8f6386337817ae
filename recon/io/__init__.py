"""Capture I/O: the EXR histogram stack (and, later, y-tal HDF5 interop)."""

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
    "spot_is_complete", "write_manifest", "write_spot", "write_stack",
]
