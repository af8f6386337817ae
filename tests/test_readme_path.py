"""The README as a newcomer follows it: the commands it shows exist and the letter example works as written."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _blocks(lang: str = "bash") -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README, re.S)


def _commands(block: str) -> list[list[str]]:
    out = []
    for line in block.splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            out.append(shlex.split(line))
    return out


def _subcommands() -> set[str]:
    from transient_mi.cli import command

    return set(command().commands)


def test_quick_start_says_how_to_get_transient_mi_on_the_path():
    assert "source .venv/bin/activate" in README
    # run.sh creates that very environment
    assert 'venv="${TRANSIENT_MI_VENV:-$here/.venv}"' in (ROOT / "run.sh").read_text()


def test_every_command_the_readme_shows_exists():
    subs = _subcommands()
    shown = [c for b in _blocks() + _blocks("text") for c in _commands(b) if c and c[0] == "transient-mi"]
    assert len(shown) >= 15
    for c in shown:
        assert c[1] in subs, f"README shows `{' '.join(c)}`, but {c[1]!r} is no transient-mi command"


def test_readme_python_names_exist():
    import recon
    import recon.io

    for name in re.findall(r"`recon\.io\.(\w+)`", README):
        assert hasattr(recon.io, name), f"README names recon.io.{name}"
    for name in re.findall(r"`recon\.(\w+)\(", README):
        assert hasattr(recon, name), f"README names recon.{name}"


def test_letter_reconstruction_example_runs_as_written_and_shows_the_letter(tmp_path):
    block = next(b for b in _blocks() if "scene-mesh" in b)
    (tmp_path / "scenes").symlink_to(ROOT / "scenes")
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    for cmd in _commands(block):
        assert cmd[0] == "transient-mi"
        r = subprocess.run([sys.executable, "-m", "transient_mi", *cmd[1:]], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, (cmd, r.stderr)
    out = tmp_path / "out" / "letter_recon"
    assert (out / "projection_z.png").is_file()
    metrics = json.loads((out / "metrics.json").read_text())
    # Deterministic (same seed, same bytes): the F's three bars at z = 0.5 m are found within a voxel in depth
    # and cover most of the letter (IoU 0.74 when written; a blob, as backprojection of the array gives, ~0.14)
    assert metrics["depth_mae_m"] < 0.01 and metrics["iou"] > 0.5, metrics


def test_scene_mesh_writes_the_hidden_shapes_not_the_wall(tmp_path):
    import trimesh

    from transient_mi.scene_mesh import hidden_mesh

    v, f, ids = hidden_mesh(ROOT / "scenes" / "nlos_letter.xml", {"letter_center": "0.1, 0, 0.6"})
    assert ids == ["letter_stem", "letter_top", "letter_middle"] and len(f) == 6
    assert np.allclose(v[:, 2], 0.6) and np.isclose((v[:, 0].min() + v[:, 0].max()) / 2, 0.1)
    v, f, ids = hidden_mesh(ROOT / "scenes" / "nlos_point_targets.xml")
    assert ids == ["target1", "target2", "target3"]  # disks, as 64-gons
    area = trimesh.Trimesh(v, f, process=False).area
    assert area == pytest.approx(3 * np.pi * 0.03 ** 2, rel=3e-3)  # 64-gon / circle = 0.9984
