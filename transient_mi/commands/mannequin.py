"""``transient-mi mannequin``: write the procedural mannequin as a PLY mesh."""

from __future__ import annotations

from pathlib import Path

import typer

from ._options import whole_number

from transient_core.errors import UserInputError


def _parse_position(text: str) -> tuple[float, float, float]:
    parts = [p.strip() for p in text.split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3:
        raise UserInputError(f"--position {text!r}: expected three comma-separated numbers x,y,z in metres, e.g. 0,0,0.5")
    return vals  # type: ignore[return-value]


def mannequin(
    output: Path = typer.Option(..., "-o", "--output", help="PLY file to write (binary; for <shape type=\"ply\">)."),
    height_m: float = typer.Option(0.70, "--height-m", help="Standing height, sole to crown, metres."),
    width_m: float = typer.Option(0.60, "--width-m", help="Width across the arms in the rest pose arms_down, metres."),
    pose: str = typer.Option("arms_down", "--pose", help="arms_down, arms_raised, one_arm_out, arms_forward or t_pose."),
    rotation_deg: float = typer.Option(0.0, "--rotation-deg", help="Turn about the vertical axis (+y), degrees; 0 faces the wall (-z)."),
    position: str = typer.Option("0,0,0.5", "--position", help="Body centre x,y,z in metres (mid-line, mid-height, torso mid-depth)."),
    detail: int = typer.Option(20, "--detail", parser=whole_number("--detail"), metavar="<int>", help="Segments around each primitive, 8 to 128."),
    joint: list[str] = typer.Option([], "--joint", metavar="NAME=DEG",
                                    help="A joint angle overriding the pose's, degrees (repeatable), e.g. "
                                         "--joint elbow_right=40; names: shoulder_abduction_*, shoulder_flexion_*, "
                                         "elbow_*, hip_*, knee_* with * = right or left."),
    report: bool = typer.Option(False, "--report", help="Also print each part's depth and three-bounce arrival time from the wall centre."),
) -> None:
    """Write the procedural mannequin (watertight PLY, world frame: wall z = 0, hidden space z > 0).

    The paper's mannequin is about 60 cm wide (across the arms) and 70 cm
    tall; those are the defaults. Same options, same bytes.
    """
    from transient_mi.scenes import mannequin as mq

    from transient_mi.scenes.mannequin_skeleton import parse_joints

    from transient_core.errors import UserInputError

    for j in joint or []:
        if not j.strip():
            raise UserInputError("--joint '': expected name=degrees (e.g. --joint elbow_right=40)")
    joints = parse_joints(",".join(joint))
    params = dict(height_m=height_m, width_m=width_m, pose=pose, rotation_deg=rotation_deg,
                  position=_parse_position(position), detail=detail, joints=joints)
    from transient_core.lock import output_lock

    with output_lock(output, "-o"):  # one writer per output file (docs/reliability.md)
        path = mq.write_mannequin(output, **params)
    mesh = mq.make_mannequin(**params)
    lo, hi = mesh.bounds
    typer.echo(
        f"wrote {path}: {len(mesh.faces)} faces, {len(mesh.vertices)} vertices, watertight, "
        f"x {lo[0]:.3f}..{hi[0]:.3f} m, y {lo[1]:.3f}..{hi[1]:.3f} m, z {lo[2]:.3f}..{hi[2]:.3f} m"
    )
    if report:
        rep = mq.mannequin_part_report(**params)
        typer.echo("part   z_min_m z_mean_m z_max_m  t_mean_ps (S = P = wall centre; hidden segments only)")
        for group, r in rep.items():
            typer.echo(f"{group:6s} {r['z_min_m']:7.3f} {r['z_mean_m']:8.3f} {r['z_max_m']:7.3f} {r['t_mean_ps']:10.1f}")


def register(app: typer.Typer) -> None:
    app.command("mannequin")(mannequin)
