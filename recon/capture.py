"""Transient NLOS captures: geometry, time axis and (lazily loaded) histograms.

A :class:`Capture` describes one NLOS measurement:

- histograms ``[spot, pixel_y, pixel_x, time]`` (one stored file per laser
  spot for ``array`` captures; one file for ``confocal`` captures, whose pixel
  ``k`` was recorded with the laser on pixel ``k``'s wall patch),
- the laser spots ``S_j`` on the relay wall and their normals,
- the wall patch centre ``P_k`` seen by each pixel and its normal,
- the laser and detector origins (needed when the first and last segments,
  laser -> wall and wall -> detector, are in the recorded path length),
- the time axis: bin ``b`` covers ``[t0_ps + b*bin_width_ps, t0_ps + (b+1)*bin_width_ps)``.

Data are read per file on demand (:meth:`Capture.spot`, :meth:`Capture.iter_spots`),
so reconstructions stream over laser spots with bounded memory;
:attr:`Capture.data` loads everything at once for small captures.

Captures come from an EXR stack (:func:`load_capture`), a y-tal HDF5 file
(:func:`recon.io.ytal.read_ytal`, also through :func:`load_capture`) or arrays
(:meth:`Capture.from_arrays`, e.g. :mod:`recon.synthetic`).
"""

from __future__ import annotations

from pathlib import Path

from transient_core.errors import UserInputError

# the type lives below the readers of other formats, which build captures too
from ._capture_type import KINDS, MODES, PULSE_KEYS, Capture  # noqa: F401  (PULSE_KEYS: recon.preprocess reads it here)

__all__ = ["Capture", "load_capture", "MODES", "KINDS"]


def load_capture(path: str | Path) -> Capture:
    """Open a capture: an EXR stack directory, a y-tal or ZNLOS HDF5 file (``.h5``/``.hdf5``) or a Stanford
    f-k confocal measurement (``.mat``, with ``tof.mat`` beside it; :func:`recon.io.real.read_fk_mat` with its
    defaults: 2 m wall, 32 ps bins).

    Only the manifest and file headers are checked here; histograms are read
    per laser spot when used.

    Raises
    ------
    UserInputError
        If the path does not exist, is not a capture, misses spot files, or
        its manifest and files disagree (the message names the file and the
        mismatch).
    """
    from transient_core import stack

    p = Path(path)
    if not p.exists():
        raise UserInputError(f"capture {str(p)!r} does not exist (expected an EXR stack directory or a .h5 file)")
    if p.is_file():
        if p.suffix.lower() in (".h5", ".hdf5", ".hdf"):
            import h5py

            from .io.ytal import read_ytal

            try:
                with h5py.File(p, "r") as f:
                    znlos = "data" in f and "H" not in f
            except OSError as e:
                raise UserInputError(f"{p}: not a readable HDF5 file ({e})") from None
            if znlos:
                from .io.real import read_znlos

                return read_znlos(p)
            return read_ytal(p)
        if p.suffix.lower() == ".mat":
            from .io.real import read_fk_mat

            return read_fk_mat(p)
        raise UserInputError(f"capture {str(p)!r} is a file with suffix {p.suffix!r}: expected an EXR stack "
                             "directory, a y-tal or ZNLOS HDF5 file (.h5, .hdf5) or a Stanford f-k .mat file")
    m = stack.read_manifest(p)
    if m["capture"] not in MODES:
        raise UserInputError(
            f"{p}: capture={m['capture']!r} is not an NLOS capture; recon needs "
            f"{' or '.join(MODES)} (a camera capture is a transient video)"
        )
    missing = stack.missing_spots(p, m)
    if missing:
        shown = ", ".join(stack.spot_filename(j) for j in missing[:5]) + (" ..." if len(missing) > 5 else "")
        raise UserInputError(
            f"{p}: {len(missing)} of {m['n_files']} spot files missing ({shown}); "
            "the render was interrupted: rerun it with --resume"
        )
    if m["status"] != "complete":
        raise UserInputError(f"{p / stack.MANIFEST_NAME}: status is {m['status']!r}; the render did not finish "
                             "(rerun it with --resume)")
    for j in range(m["n_files"]):
        if not stack.spot_is_complete(p, j, m):
            stack.read_spot(p, j, m)  # raises StackError naming the file and the mismatch
    manifest = m
    # multi-channel captures (colour, Stokes) are reconstructed from one intensity per bin (stack.intensity)
    return Capture.from_manifest(manifest, lambda j: stack.read_intensity(p, j, manifest), source=str(p))
