"""Shape ``mannequin``: the procedural mannequin as a Mitsuba mesh, generated when the scene loads."""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from transient_mi._upload import upload
from transient_mi.props import PluginParameterError, get_float, get_int, get_vector3

PLUGIN = ("shape", "mannequin", "make_mannequin_shape")


def make_mannequin_shape(props: mi.Properties):
    r"""Shape ``mannequin``: :func:`transient_mi.scenes.mannequin.make_mannequin` as a mesh.

    Lets an XML scene place the mannequin with ``$name`` parameters (pose,
    size, position) and no separate build step; the mesh is identical to
    the one ``transient-mi mannequin`` writes with the same parameters, so
    it can serve as ground truth. Shading uses face normals.

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - ``height_m``, ``width_m``
         - float
         - Sole to crown, and across the arms in the default pose
           (default 0.70 x 0.60 m).
       * - ``pose``
         - string
         - ``arms_down`` (default), ``arms_raised``, ``one_arm_out``,
           ``arms_forward``, ``t_pose``.
       * - ``rotation_deg``
         - float
         - Rotation about the vertical (y) axis (default 0).
       * - ``position``
         - point
         - Body centre, metres (default 0, 0, 0.5: 50 cm in front of a
           relay wall in the plane z = 0).
       * - ``joints``
         - string
         - Joint angles overriding the pose's, degrees, e.g.
           ``elbow_right=40,knee_left=20`` (default: none;
           :mod:`transient_mi.scenes.mannequin_skeleton`).
       * - ``detail``
         - integer
         - Tessellation level (default 20, ~3000 faces).
       * - ``bsdf`` child
         - BSDF
         - Material (default: Mitsuba's default diffuse).
    """
    from transient_mi.scenes.mannequin import DEFAULTS, POSES, make_mannequin

    name = "mannequin"
    pose = props.get("pose", DEFAULTS["pose"]) if "pose" in props else DEFAULTS["pose"]
    if pose not in POSES:
        raise PluginParameterError(f"{name}: pose={pose!r}; allowed: {', '.join(POSES)}")
    kw = dict(
        height_m=get_float(props, name, "height_m", DEFAULTS["height_m"], min_value=0.0, min_exclusive=True),
        width_m=get_float(props, name, "width_m", DEFAULTS["width_m"], min_value=0.0, min_exclusive=True),
        pose=pose,
        rotation_deg=get_float(props, name, "rotation_deg", DEFAULTS["rotation_deg"]),
        position=get_vector3(props, name, "position", DEFAULTS["position"]),
        detail=get_int(props, name, "detail", DEFAULTS["detail"], min_value=4, max_value=200),
        joints=props.get("joints", "") if "joints" in props else "",
    )
    try:
        tm = make_mannequin(**kw)
    except ValueError as e:  # (UserInputError included)
        raise PluginParameterError(f"{name}: {e}") from None
    v = np.ascontiguousarray(tm.vertices, dtype=np.float32)
    f = np.ascontiguousarray(tm.faces, dtype=np.uint32)
    mesh = mi.Mesh(name, len(v), len(f), props=props, has_vertex_normals=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = upload(mi.Float, v)
    params["faces"] = upload(mi.UInt32, f)
    params.update()
    return mesh
