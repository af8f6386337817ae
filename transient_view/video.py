"""Time slices of a capture as a video (GIF with Pillow, MP4 with imageio-ffmpeg), each frame stamped in ps.

Frame ``k`` shows time bin ``first + k * stride`` of one laser spot's
histograms ``[H, W, n_bins]``, colour-mapped with one brightness scale for the
whole video (``normalize="global"``: the 99.9th percentile of the shown bins,
so the light front's fall-off stays visible) or per frame
(``normalize="frame"``), enlarged ``scale`` times with nearest-neighbour
pixels (the frame is widened, if needed, to hold the whole time stamp), below a
banner with the bin's centre time in picoseconds.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError

__all__ = ["write_video", "video_frames", "FORMATS", "NORMALIZE"]

FORMATS = (".gif", ".mp4")
NORMALIZE = ("global", "frame")
#: Frames are at least this many pixels wide unless ``scale`` is given.
MIN_WIDTH_PX = 256
#: Largest frame side a video is drawn at, pixels (a 4K frame is 3840 wide).
MAX_SIDE_PX = 8192
BANNER_PX = 24


def _scale_for(width: int, height: int) -> int:
    return max(1, math.ceil(MIN_WIDTH_PX / max(width, height)))


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the bitmap font only
        return ImageFont.load_default()


def video_frames(histograms: np.ndarray, times_ps: np.ndarray, bins: range, *, scale: int, normalize: str = "global",
                 cmap: str = "inferno", pad_to: int = 1):
    """Yield RGB frames ``uint8[height, width, 3]`` for the time bins ``bins`` of ``histograms[H, W, T]``.

    ``pad_to`` rounds the frame size up to a multiple (video codecs want 2 or 16).
    """
    from matplotlib import colormaps
    from PIL import Image, ImageDraw

    lut = (colormaps[cmap](np.linspace(0, 1, 256))[:, :3] * 255).astype(np.uint8)
    H, W, _ = histograms.shape
    sel = histograms[:, :, bins.start:bins.stop:bins.step]
    top = float(np.percentile(sel, 99.9)) if sel.size else 0.0
    if not top > 0:
        top = float(sel.max()) if sel.size and sel.max() > 0 else 1.0
    font = _font(14)
    stamps = [f"t = {times_ps[b]:.1f} ps" for b in bins]
    text_w = max(int(math.ceil(font.getlength(s))) for s in stamps) + 8 if stamps else 0
    # wide enough for the whole time stamp: every frame differs from the next (GIF writers merge equal frames)
    fw, fh = max(W * scale, text_w), H * scale + BANNER_PX
    fw, fh = -(-fw // pad_to) * pad_to, -(-fh // pad_to) * pad_to
    for b, stamp in zip(bins, stamps):
        img = histograms[:, :, b].astype(np.float64)
        hi = top if normalize == "global" else (float(img.max()) or 1.0)
        idx = np.clip(img / hi * 255.0, 0, 255).astype(np.uint8)
        rgb = lut[idx[::-1]]  # row 0 (smallest wall y) at the bottom, as on the wall
        rgb = np.repeat(np.repeat(rgb, scale, axis=0), scale, axis=1)
        frame = np.zeros((fh, fw, 3), dtype=np.uint8)
        frame[BANNER_PX:BANNER_PX + rgb.shape[0], :rgb.shape[1]] = rgb
        im = Image.fromarray(frame)
        ImageDraw.Draw(im).text((4, 4), stamp, fill=(255, 255, 255), font=font)
        yield np.asarray(im)


def write_video(capture_path, out, *, spot: int = 0, fps: float = 20.0, stride: int = 1, first_bin: int = 0,
                last_bin: int | None = None, scale: int | None = None, normalize: str = "global",
                cmap: str = "inferno") -> dict:
    """Write the time slices of one spot of a capture as ``out`` (``.gif`` or ``.mp4``), atomically.

    Parameters
    ----------
    capture_path : path
        An EXR stack directory or a y-tal HDF5 file.
    out : path
        ``.gif`` (Pillow) or ``.mp4`` (needs the ``view`` extra's imageio-ffmpeg).
    spot : int
        Stored file (laser spot) to show.
    fps : float
        Frames per second (> 0).
    stride, first_bin, last_bin : int
        Bins ``first_bin, first_bin + stride, ...`` up to ``last_bin`` (inclusive; default the last bin).
    scale : int, optional
        Screen pixels per SPAD pixel (default: frames at least 256 px wide).
    normalize : {"global", "frame"}
    cmap : str
        A matplotlib colour map name.

    Returns
    -------
    dict
        ``path``, ``n_frames``, ``width``, ``height`` (pixels), ``fps``, ``bins`` shown.
    """
    from transient_core.atomic import atomic_file, check_output_location
    from transient_core.lock import output_lock

    from .data import CaptureData

    out = Path(out)
    suf = out.suffix.lower()
    if suf not in FORMATS:
        raise UserInputError(f"-o {str(out)!r}: the suffix must be one of {', '.join(FORMATS)}")
    if normalize not in NORMALIZE:
        raise UserInputError(f"--normalize {normalize!r}: allowed {', '.join(NORMALIZE)}")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise UserInputError(f"--fps {fps!r}: must be a number > 0")
    if int(stride) < 1:
        raise UserInputError(f"--stride {stride!r}: must be >= 1")
    if scale is not None and int(scale) < 1:
        raise UserInputError(f"--scale {scale!r}: must be >= 1")
    from matplotlib import colormaps

    if cmap not in colormaps:
        raise UserInputError(f"--cmap {cmap!r}: not a matplotlib colour map (e.g. inferno, viridis, gray)")
    writer = None
    if suf == ".mp4":
        try:
            import imageio_ffmpeg as writer
        except ImportError:
            raise UserInputError(f"-o {str(out)!r}: MP4 needs imageio-ffmpeg; install the viewer extra "
                                 "(pip install 'transient-mi[view]') or write a .gif") from None
    if not out.parent.is_dir():
        raise UserInputError(f"-o {str(out)!r}: the directory {str(out.parent)!r} does not exist")
    if out.is_dir():
        raise UserInputError(f"-o {str(out)!r}: is a directory; give a file name ending in {suf}")
    check_output_location(out, "-o")  # a place this process can write into (not /proc, not read-only)
    data = CaptureData(Path(capture_path))
    if not 0 <= int(spot) < data.n_files:
        raise UserInputError(f"--spot {spot}: this capture has spots 0..{data.n_files - 1}")
    last = data.n_bins - 1 if last_bin is None else int(last_bin)
    if not 0 <= int(first_bin) <= last < data.n_bins:
        raise UserInputError(f"--first-bin {first_bin}, --last-bin {last_bin}: need 0 <= first <= last <= "
                             f"{data.n_bins - 1}")
    bins = range(int(first_bin), last + 1, int(stride))
    hist = data.spot(int(spot))
    s = int(scale) if scale is not None else _scale_for(data.width, data.height)
    if s * max(data.width, data.height) > MAX_SIDE_PX:
        raise UserInputError(f"--scale {s}: frames of {s * data.width}x{s * data.height} px; at most {MAX_SIDE_PX} "
                             f"px a side (--scale <= {max(1, MAX_SIDE_PX // max(data.width, data.height))} for this "
                             "capture)")
    frames = video_frames(hist, data.times_ps, bins, scale=s, normalize=normalize, cmap=cmap,
                          pad_to=16 if suf == ".mp4" else 1)
    first = next(frames)
    h, w = first.shape[:2]
    with output_lock(out, "-o"):  # one writer per output file (docs/reliability.md)
        with atomic_file(out, suffix=".tmp" + suf) as tmp:
            if suf == ".gif":
                from PIL import Image

                ims = [Image.fromarray(first)] + [Image.fromarray(f) for f in frames]
                ims[0].save(tmp, format="GIF", save_all=True, append_images=ims[1:],
                            duration=max(1, round(1000.0 / fps)), loop=0, optimize=False, disposal=1)
            else:
                gen = writer.write_frames(str(tmp), (w, h), fps=float(fps), codec="libx264", pix_fmt_out="yuv420p",
                                          macro_block_size=16, quality=7, ffmpeg_log_level="error")
                gen.send(None)
                gen.send(np.ascontiguousarray(first))
                for f in frames:
                    gen.send(np.ascontiguousarray(f))
                gen.close()
    return {"path": str(out), "n_frames": len(bins), "width": w, "height": h, "fps": float(fps),
            "bins": [bins.start, bins.stop - 1, bins.step]}
