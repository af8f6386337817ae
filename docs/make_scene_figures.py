"""Render the README's pictures of the physics-breadth scenes with the command a user would type.

Usage::

    python docs/make_scene_figures.py [--only NAME ...] [--keep DIR]

Each entry renders one embedded scene with ``transient-mi render`` (seeded, so the same bytes every
time). The colour Cornell box is the capture's own ``preview.png``; each NLOS scene is rendered twice,
with its effect and without it (``-D`` values below), and drawn as the pixel-summed histogram of
laser spot 0 for both (log scale) beside the time-integrated image with the effect (wall return
excluded), into ``docs/img/NAME.png``:

=====================  ===============================================================================
``cornell_box_rgb``    ``scenes/cornell_box.xml`` in ``llvm_ad_rgb``: R, G, B per time bin
``glass_window_nlos``  ``scenes/glass_window_nlos.xml``: an NLOS capture through a glass pane
``fog_nlos``           ``scenes/fog_nlos.xml``: an NLOS capture in homogeneous fog
=====================  ===============================================================================
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: name -> (scene, extra arguments of ``transient-mi render``)
FIGURES = {
    "cornell_box_rgb": ("scenes/cornell_box.xml", ["--variant", "llvm_ad_rgb", "--spp", "256", "--seed", "1"]),
    "glass_window_nlos": ("scenes/glass_window_nlos.xml", ["--seed", "1", "-D", "spots_x=1", "-D", "spots_y=1"]),
    "fog_nlos": ("scenes/fog_nlos.xml", ["--seed", "1", "-D", "spots_x=1", "-D", "spots_y=1"]),
}
#: NLOS figures: (label with the effect, label without, -D arguments that remove the effect, histogram
#: drawn with the wall return (log scale) or without it (linear, the hidden object's return))
COMPARE = {
    "glass_window_nlos": ("through the 1 cm glass pane", "index-matched pane (window_ior=1: no window)",
                          ["-D", "window_ior=1"], False),
    "fog_nlos": ("in fog (sigma_t 0.2 /m, albedo 0.9)", "clear air", ["-D", "sigma_t=1e-9"], True),
}


def cli() -> list[str]:
    """The ``transient-mi`` command of this interpreter's environment."""
    exe = Path(sys.executable).with_name("transient-mi")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "transient_mi.cli"]


def _render(scene: str, out: Path, extra: list[str]) -> Path:
    cmd = cli() + ["render", str(ROOT / scene), "-o", str(out)] + extra
    print("$", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT)
    return out


def compare_figure(dest: Path, with_effect: Path, without: Path, labels: tuple[str, str], title: str,
                   log: bool = True) -> None:
    """Pixel-summed histogram of spot 0 with and without the effect (``log``: all of it on a log scale, else
    the hidden object's return on a linear scale, wall return excluded), and the image with the effect."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    sys.path.insert(0, str(ROOT))
    from transient_core import stack
    from transient_mi.preview import wall_return_mask

    fig = Figure(figsize=(13, 3.8))
    ax_img, ax = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1, 2.6]})
    for d, label, colour in ((with_effect, labels[0], "C3"), (without, labels[1], "C0")):
        m = stack.read_manifest(d)
        h = stack.intensity(stack.read_spot(d, 0, m), m).astype(np.float64)
        t = m["time"]
        t_ns = (t["t0_ps"] + (np.arange(t["n_bins"]) + 0.5) * t["bin_width_ps"]) / 1000.0
        h_hidden = np.where(wall_return_mask(m, 0, h.shape), 0.0, h)
        if log:
            ax.semilogy(t_ns, np.maximum(h.sum(axis=(0, 1)), 1e-30), color=colour, lw=0.9, label=label)
        else:
            prof = h_hidden.sum(axis=(0, 1))
            ax.plot(t_ns, prof, color=colour, lw=0.9, label=label, drawstyle="steps-mid")
            on = np.flatnonzero(prof > 0.01 * prof.max())
            ax.set_xlim(t_ns[on[0]] - 0.3, t_ns[on[-1]] + 0.3)  # the hidden object's return
        if d == with_effect:
            hidden = h_hidden.sum(axis=-1)
            im = ax_img.imshow(hidden, origin="lower", cmap="viridis")
            fig.colorbar(im, ax=ax_img, fraction=0.046)
            ax_img.set_title(f"photons/pulse, {labels[0]}\n(wall return excluded)", fontsize=9)
            top = h.sum(axis=(0, 1)).max()
    if log:
        ax.set_ylim(top * 1e-7, top * 3)
    ax.set_xlabel("time since the pulse left the laser (ns)")
    ax.set_ylabel("photons per pulse per bin,\nsummed over pixels" + ("" if log else "\n(wall return excluded)"))
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=9)
    fig.tight_layout()
    fig.savefig(dest, dpi=90)


def render_figure(name: str, work: Path) -> Path:
    scene, extra = FIGURES[name]
    dest = ROOT / "docs" / "img" / f"{name}.png"
    out = _render(scene, work / name, extra)
    if name not in COMPARE:
        shutil.copyfile(out / "preview.png", dest)
    else:
        lab_with, lab_without, remove, log = COMPARE[name]
        ref = _render(scene, work / f"{name}_without", extra + remove)
        compare_figure(dest, out, ref, (lab_with, lab_without), f"{scene}: laser spot 0, every pixel", log=log)
    print("wrote", dest.relative_to(ROOT), flush=True)
    return dest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", choices=sorted(FIGURES), help="render only these figures")
    ap.add_argument("--keep", type=Path, help="keep the captures in this directory (default: a temporary one)")
    a = ap.parse_args(argv)
    names = a.only or list(FIGURES)
    if a.keep:
        a.keep.mkdir(parents=True, exist_ok=True)
        for n in names:
            render_figure(n, a.keep)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            for n in names:
                render_figure(n, Path(tmp))
    return 0


if __name__ == "__main__":
    sys.exit(main())
