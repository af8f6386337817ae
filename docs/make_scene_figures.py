"""Render the README's pictures of the physics-breadth scenes with the command a user would type.

Usage::

    python docs/make_scene_figures.py [--only NAME ...] [--keep DIR]

Each entry renders one embedded scene with ``transient-mi render`` (seeded, so the same bytes every
time) and copies the capture's ``preview.png`` to ``docs/img/NAME.png``:

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

ROOT = Path(__file__).resolve().parents[1]

#: name -> (scene, extra arguments of ``transient-mi render``)
FIGURES = {
    "cornell_box_rgb": ("scenes/cornell_box.xml", ["--variant", "llvm_ad_rgb", "--spp", "256", "--seed", "1"]),
    "glass_window_nlos": ("scenes/glass_window_nlos.xml", ["--seed", "1"]),
    "fog_nlos": ("scenes/fog_nlos.xml", ["--seed", "1"]),
}


def cli() -> list[str]:
    """The ``transient-mi`` command of this interpreter's environment."""
    exe = Path(sys.executable).with_name("transient-mi")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "transient_mi.cli"]


def render_figure(name: str, work: Path) -> Path:
    scene, extra = FIGURES[name]
    out = work / name
    cmd = cli() + ["render", str(ROOT / scene), "-o", str(out)] + extra
    print("$", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT)
    dest = ROOT / "docs" / "img" / f"{name}.png"
    shutil.copyfile(out / "preview.png", dest)
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
