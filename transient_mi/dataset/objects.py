"""Object generators: procedural meshes written into each dataset item.

A spec's ``object:`` section names a generator ``kind`` and its parameters;
for every item the worker writes the mesh into the item directory as
``mesh.ply`` (the ground truth) and passes it to the scene as the ``-D``
parameter the spec names (``define``, default ``mesh``).

Kinds
-----
``mannequin``
    :func:`transient_mi.scenes.mannequin.write_mannequin`. Parameters:
    ``height_m``, ``width_m``, ``pose``, ``rotation_deg``, ``position``
    (``[x, y, z]`` metres), ``position_x`` / ``position_y`` / ``position_z``
    (one component each, overriding ``position``; handy to draw one at a
    time), ``detail`` and ``joints`` (joint angles overriding the pose's, degrees: a mapping such as
    ``{elbow_right: 40}`` or ``"elbow_right=40,knee_left=20"``). Defaults: those of the ``mannequin``
    command.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

#: File name of the generated mesh inside an item directory.
MESH_NAME = "mesh.ply"


def _mannequin_defaults() -> dict[str, Any]:
    from transient_mi.scenes.mannequin import DEFAULTS

    d = dict(DEFAULTS)
    d["position"] = list(d["position"])
    return d


def _mannequin_resolve(given: dict[str, Any]) -> dict[str, Any]:
    """Fill defaults, apply ``position_*`` components, validate; return write_mannequin's kwargs."""
    from transient_mi.scenes import mannequin as mq

    p = _mannequin_defaults()
    for k, v in given.items():
        if k not in ("position_x", "position_y", "position_z"):
            p[k] = v
    pos = p["position"]
    if not isinstance(pos, (list, tuple)) or len(pos) != 3:
        from transient_core.errors import UserInputError

        raise UserInputError(f"object.position={pos!r}: expected three numbers [x, y, z] in metres")
    pos = list(pos)
    for i, axis in enumerate("xyz"):
        if f"position_{axis}" in given:
            pos[i] = given[f"position_{axis}"]
    p["position"] = pos
    joints = p.get("joints")
    h, w, pose, rot, position, detail, _ = mq._validate(p["height_m"], p["width_m"], p["pose"], p["rotation_deg"],
                                                        p["position"], p["detail"], joints)
    out = {"height_m": h, "width_m": w, "pose": pose, "rotation_deg": rot, "position": list(position),
           "detail": detail}
    if joints:  # (only when given: items without joints keep their bytes)
        from transient_mi.scenes.mannequin_skeleton import parse_joints

        out["joints"] = {k: float(v) for k, v in (parse_joints(joints) if isinstance(joints, str) else joints).items()}
    return out


def _mannequin_write(path: Path, params: dict[str, Any]) -> Path:
    from transient_mi.scenes.mannequin import write_mannequin

    kw = dict(params)
    kw["position"] = tuple(kw["position"])
    return write_mannequin(path, **kw)


def _mannequin_command(params: dict[str, Any], out: str) -> str:
    x, y, z = params["position"]
    return (f"transient-mi mannequin -o {out} --height-m {params['height_m']!r} --width-m {params['width_m']!r} "
            f"--pose {params['pose']} --rotation-deg {params['rotation_deg']!r} --position {x!r},{y!r},{z!r} "
            f"--detail {params['detail']}"
            + "".join(f" --joint {k}={v!r}" for k, v in params.get("joints", {}).items()))


@dataclass(frozen=True)
class ObjectKind:
    """A mesh generator usable in a spec's ``object:`` section."""

    name: str
    params: tuple[str, ...]
    resolve: Callable[[dict], dict]
    write: Callable[[Path, dict], Path]
    command: Callable[[dict, str], str]


OBJECT_KINDS: dict[str, ObjectKind] = {
    "mannequin": ObjectKind(
        "mannequin",
        ("height_m", "width_m", "pose", "rotation_deg", "position", "position_x", "position_y", "position_z",
         "detail", "joints"),
        _mannequin_resolve, _mannequin_write, _mannequin_command),
}
