"""``transient-mi scene-mesh``: the hidden geometry of a scene as a PLY mesh (for ``recon --ground-truth``)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer


def scene_mesh(
    scene: Path = typer.Argument(..., help="Mitsuba XML scene (an NLOS scene: relay wall in z = 0)."),
    output: Path = typer.Option(..., "-o", "--output", help="PLY file to write (binary, world frame, metres)."),
    define: Optional[List[str]] = typer.Option(None, "-D", "--define", help="Scene parameter name=value, as given "
                                               "to render. Repeatable."),
) -> None:
    """Write every shape of SCENE in the hidden space z > 0 (not the relay wall) as one triangle mesh: the ground
    truth for `transient-mi recon --ground-truth`."""
    from transient_mi.scene_io import parse_defines
    from transient_mi.scene_mesh import hidden_mesh
    from transient_mi.scenes._ply import write_ply

    v, f, ids = hidden_mesh(scene, parse_defines(define))
    from transient_core.lock import output_lock

    with output_lock(output, "-o"):  # one writer per output file (docs/reliability.md)
        path = write_ply(output, v, f)
    lo, hi = v.min(0), v.max(0)
    typer.echo(f"wrote {path}: {len(f)} faces from {len(ids)} shape(s) ({', '.join(ids)}), "
               f"x {lo[0]:.3f}..{hi[0]:.3f} m, y {lo[1]:.3f}..{hi[1]:.3f} m, z {lo[2]:.3f}..{hi[2]:.3f} m")


def register(app: typer.Typer) -> None:
    app.command("scene-mesh")(scene_mesh)
