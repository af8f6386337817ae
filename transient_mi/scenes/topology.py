r"""Generated NLOS scenes whose hidden shape has another topology than the embedded ones (a square, a letter F):
test and benchmark material for ``transient-mi fit --model mesh`` on shapes it was not tuned on.

Two shapes, both about 50 cm behind the relay wall, in the world frame of the ``nlos_*.xml`` scenes (metres;
the wall in z = 0, the hidden space z > 0, "up" +y):

``chair``
    A chair-like union of six closed boxes facing the wall: a seat (30 x 3 x 20 cm, its top 1 cm below the
    wall's centre line), a back rest (30 x 23 x 3 cm) standing on the seat's far end, four legs of 3 x 18 x 3 cm
    under the seat's corners (44 cm tall in all, its front 40 cm from the wall). Boxes touch but do not overlap;
    each is wound outwards with its own vertices (flat faces). Disconnected parts seen from the wall, a
    surface nearly edge-on (the seat), self-occlusion (the back legs behind the front ones) and a back side
    no three-bounce light reaches.
``holed_plate``
    A 40 cm square plate with a round hole of 12 cm radius at its centre (genus one: an annulus), one-sided
    (wound towards the wall, as the embedded scenes' rectangles), turned 20 degrees about the horizontal axis
    (its top away from the wall), centred 50 cm from the wall. A fit that closes the hole but is right
    elsewhere (:func:`closed_plate_mesh`) scores a silhouette IoU of ``HOLED_PLATE_CLOSED_IOU`` (0.72) over the
    whole plate, and less on a capture that sees its middle only (0.59 on the benchmark's 32 cm square): the
    metric sees the hole.

:func:`write_topology_scene` writes ``<name>.ply`` and ``<name>.xml`` into a folder. The XML is
``nlos_tilted_plane.xml`` (its device, laser, wall, time axis and every ``-D`` parameter) with the square
replaced by the mesh file (``shape_albedo``, 0.8 by default), so a capture of it renders, detects and fits as
the embedded scenes do, and :func:`transient_mi.scene_mesh.hidden_mesh` reads its ground truth.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError

__all__ = ["TOPOLOGY_SHAPES", "HOLED_PLATE_CLOSED_IOU", "chair_mesh", "holed_plate_mesh", "closed_plate_mesh",
           "topology_mesh",
           "write_topology_scene"]

TOPOLOGY_SHAPES = ("chair", "holed_plate")

#: Holed plate: side (m), hole radius (m), tilt about the x axis (degrees), centre (m).
PLATE_SIDE_M = 0.4
HOLE_RADIUS_M = 0.12
PLATE_TILT_DEG = 20.0
PLATE_CENTER = (0.0, 0.0, 0.5)
#: The silhouette IoU of the closed square against the holed plate (areas; the tilt scales both alike).
HOLED_PLATE_CLOSED_IOU = (PLATE_SIDE_M ** 2 - math.pi * HOLE_RADIUS_M ** 2) / PLATE_SIDE_M ** 2

#: Chair boxes ``(x0, x1, y0, y1, z0, z1)`` (m).
_SEAT = (-0.15, 0.15, -0.04, -0.01, 0.40, 0.60)
_BACK = (-0.15, 0.15, -0.01, 0.22, 0.57, 0.60)
_LEGS = tuple((x0, x0 + 0.03, -0.22, -0.04, z0, z0 + 0.03) for z0 in (0.40, 0.57) for x0 in (-0.15, 0.12))


def _box(b) -> tuple[np.ndarray, np.ndarray]:
    """A closed box ``(x0, x1, y0, y1, z0, z1)`` as 12 triangles wound outwards, 4 vertices per side."""
    x0, x1, y0, y1, z0, z1 = b
    sides = [  # (four corners counter-clockwise seen from outside)
        [(x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0)],  # -z (towards the wall)
        [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)],  # +z
        [(x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)],  # -x
        [(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)],  # +x
        [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)],  # -y
        [(x0, y1, z0), (x0, y1, z1), (x1, y1, z1), (x1, y1, z0)],  # +y
    ]
    v = np.array(sides, dtype=np.float64).reshape(-1, 3)
    q = 4 * np.arange(6)[:, None]
    f = np.concatenate([q + [0, 1, 2], q + [0, 2, 3]])
    return v, f


def chair_mesh() -> tuple[np.ndarray, np.ndarray]:
    """``(vertices [V, 3] m, faces [F, 3])`` of the chair (module docstring): 6 boxes, 72 triangles."""
    verts, faces, n = [], [], 0
    for b in (_SEAT, _BACK) + _LEGS:
        v, f = _box(b)
        verts.append(v)
        faces.append(f + n)
        n += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def holed_plate_mesh(segments: int = 48, rings: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices [V, 3] m, faces [F, 3])`` of the holed plate (module docstring).

    ``segments`` angles (a multiple of 4 with the square's corners among them) and ``rings`` rings of quads
    between the hole's circle and the square's boundary, each quad split in two triangles wound towards -z.
    """
    if segments % 8:
        raise ValueError("segments must be a multiple of 8 (the square's corners at 45 degrees)")
    a = 2 * np.pi * np.arange(segments) / segments
    c, s = np.cos(a), np.sin(a)
    inner = HOLE_RADIUS_M * np.stack([c, s], axis=1)
    outer = 0.5 * PLATE_SIDE_M * np.stack([c, s], axis=1) / np.maximum(np.abs(c), np.abs(s))[:, None]
    t = np.linspace(0.0, 1.0, rings + 1)
    uv = (inner[None] + t[:, None, None] * (outer - inner)[None]).reshape(-1, 2)  # [ring, angle]
    faces = []
    for r in range(rings):
        for k in range(segments):
            p, q = r * segments + k, r * segments + (k + 1) % segments
            faces += [[p, p + segments, q], [q, p + segments, q + segments]]
    tilt = math.radians(PLATE_TILT_DEG)
    x, y = uv[:, 0], uv[:, 1]
    v = np.stack([x, y * math.cos(tilt), y * math.sin(tilt)], axis=1) + np.asarray(PLATE_CENTER)
    f = np.asarray(faces, dtype=np.int64)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    if np.any(n[:, 2] > 0):  # (wound towards the wall, -z)
        f = f[:, ::-1].copy()
    return v, f


def closed_plate_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The holed plate's square without its hole (two triangles, the same pose): what a fit that cannot open
    the hole can reach at best."""
    h, tilt = 0.5 * PLATE_SIDE_M, math.radians(PLATE_TILT_DEG)
    uv = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    v = np.stack([uv[:, 0], uv[:, 1] * math.cos(tilt), uv[:, 1] * math.sin(tilt)], axis=1) + np.asarray(PLATE_CENTER)
    return v, np.array([[0, 2, 1], [0, 3, 2]])


def topology_mesh(name: str) -> tuple[np.ndarray, np.ndarray]:
    """The mesh of the shape called ``name`` (one of :data:`TOPOLOGY_SHAPES`)."""
    if name == "chair":
        return chair_mesh()
    if name == "holed_plate":
        return holed_plate_mesh()
    raise UserInputError(f"shape {name!r} is not a generated topology scene; allowed: {', '.join(TOPOLOGY_SHAPES)}")


def write_topology_scene(name: str, folder) -> Path:
    """Write ``<name>.ply`` and ``<name>.xml`` (module docstring) into ``folder`` (created); returns the XML's
    path. Same name, same bytes."""
    from . import scene_path
    from ._ply import write_bytes_atomic, write_ply

    v, f = topology_mesh(name)
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    write_ply(d / f"{name}.ply", v, f)
    xml = scene_path("nlos_tilted_plane").read_text()
    xml = re.sub(r"  plane_center .*?plane_albedo\.\n", f"  shape_albedo (the hidden {name}'s reflectance).\n", xml,
                 flags=re.S)
    xml = xml.replace("A tilted Lambertian square (a plane at an angle to the wall).",
                      f"Generated by transient_mi.scenes.topology: the hidden {name} ({name}.ply) behind the relay "
                      "wall.")
    xml = re.sub(r'    <default name="(plane_center|plane_size|tilt_deg|plane_albedo)".*\n', "", xml)
    xml = xml.replace('    <default name="wall_albedo"', '    <default name="shape_albedo" value="0.8"/>\n'
                      '    <default name="wall_albedo"')
    shape = (f'    <shape type="ply" id="{name}">\n'
             f'        <string name="filename" value="{name}.ply"/>\n'
             '        <boolean name="face_normals" value="true"/>\n'
             '        <bsdf type="diffuse">\n'
             '            <rgb name="reflectance" value="$shape_albedo"/>\n'
             '        </bsdf>\n'
             '    </shape>\n')
    xml, n = re.subn(r'    <!-- rectangle spans.*?</shape>\n', shape, xml, flags=re.S)
    if n != 1 or "$plane" in xml or "$tilt" in xml:
        raise RuntimeError("nlos_tilted_plane.xml changed: write_topology_scene no longer finds its square")
    return write_bytes_atomic(d / f"{name}.xml", xml.encode(), what="scene file")
