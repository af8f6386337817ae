"""The mannequin's skeleton: joints, bones and the rigid transform of every bone for a set of joint angles.

Pure numpy (no Mitsuba, no mesh library): :mod:`transient_mi.scenes.mannequin` builds the mesh from it and
:mod:`transient_mi.fit.twin` evaluates the same transforms in Dr.Jit (differentiable in the angles).

Frame and units: the mannequin's body frame in units of its height (y from the sole up, x the body's right
side, -z towards the relay wall), before :func:`~transient_mi.scenes.mannequin.make_mannequin` scales,
rotates and places the figure.

Bones and joints (angles in degrees)
------------------------------------
=====================  ==========================================================================
``root``               head, neck, torso (never moves relative to the body frame)
``upper_arm_{side}``   about the shoulder: ``shoulder_abduction_{side}`` (the arm's angle from
                       hanging straight down, in the frontal plane: 90 = horizontal, out to the
                       side; 180 = straight up), then ``shoulder_flexion_{side}`` (the arm's plane
                       tilted towards the wall about the body's x axis: 90 = pointing at the wall
                       when abduction is 0)
``forearm_{side}``     ``elbow_{side}``: flexion of the forearm towards the front of the upper arm
                       (0 = straight)
``thigh_{side}``       ``hip_{side}``: flexion of the leg towards the wall (0 = standing)
``shin_{side}``        ``knee_{side}``: flexion of the shin backwards, away from the wall (0 = straight)
=====================  ==========================================================================

``side`` is ``right`` (+x) or ``left`` (-x); the left side is the mirror image of the right (x -> -x) for
equal angles. A bone's transform maps its rest position (arms hanging straight down, legs straight) to the
posed one: ``v_posed = R v_rest + t``. Rotation matrices: ``Rx(a)`` and ``Rz(a)`` are right-handed
rotations by ``a`` about x and z; the shoulder is ``Rx(flexion) Rz(abduction)`` (right side), the elbow
``Rx(elbow)``, the hip ``Rx(hip)``, the knee ``Rx(-knee)``, each about its joint's pivot and composed
from the root outwards.
"""

from __future__ import annotations

import math

import numpy as np

from transient_core.errors import UserInputError

__all__ = ["JOINTS", "JOINT_RANGES_DEG", "BONES", "SHOULDER", "ELBOW_DROP", "HIP", "KNEE", "pose_joint_angles",
           "resolve_joints", "bone_transforms", "parse_joints"]

SIDES = ("right", "left")
#: Joint angles, degrees, in a fixed order (the fit's parameter order).
JOINTS: tuple[str, ...] = tuple(f"{j}_{s}" for s in SIDES for j in
                                ("shoulder_abduction", "shoulder_flexion", "elbow", "hip", "knee"))
#: Allowed range of each kind of joint angle, degrees (inclusive).
JOINT_RANGES_DEG: dict[str, tuple[float, float]] = {
    "shoulder_abduction": (0.0, 180.0), "shoulder_flexion": (-90.0, 180.0), "elbow": (0.0, 150.0),
    "hip": (-45.0, 120.0), "knee": (0.0, 150.0),
}
#: Bones, parents before children.
BONES: tuple[str, ...] = ("root",) + tuple(f"{b}_{s}" for s in SIDES for b in ("upper_arm", "forearm", "thigh", "shin"))

# Joint pivots of the right side, body frame (units of the height); the left side is mirrored.
SHOULDER = (0.14, 0.745, 0.0)
ELBOW_DROP = 0.19  # shoulder to elbow along the arm
HIP = (0.06, 0.47, 0.0)
KNEE = (0.07, 0.26, 0.0)
_ARM_FORWARD_DEG = 30.0


def _rx(a_deg: float) -> np.ndarray:
    a = math.radians(a_deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rz(a_deg: float) -> np.ndarray:
    a = math.radians(a_deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose_joint_angles(pose: str, rest_deg: float) -> dict[str, float]:
    """Joint angles of a named pose (:data:`~transient_mi.scenes.mannequin.POSES`); ``rest_deg`` is the
    arms' angle from vertical in ``arms_down`` (set by the width)."""
    arm_down = {"shoulder_abduction": rest_deg, "shoulder_flexion": _ARM_FORWARD_DEG}
    arms = {
        "arms_down": (arm_down, arm_down),
        "arms_raised": ({"shoulder_abduction": 155.0, "shoulder_flexion": -15.0},) * 2,
        "one_arm_out": ({"shoulder_abduction": 90.0, "shoulder_flexion": 0.0}, arm_down),
        "arms_forward": ({"shoulder_abduction": 5.0, "shoulder_flexion": 90.0},) * 2,
        "t_pose": ({"shoulder_abduction": 90.0, "shoulder_flexion": 0.0},) * 2,
    }[pose]
    out = {}
    for side, a in zip(SIDES, arms):
        out.update({f"{k}_{side}": float(v) for k, v in a.items()})
        out.update({f"elbow_{side}": 0.0, f"hip_{side}": 0.0, f"knee_{side}": 0.0})
    return {j: out[j] for j in JOINTS}


def _kind(joint: str) -> str:
    return joint.rsplit("_", 1)[0]


def resolve_joints(pose: str, rest_deg: float, joints=None) -> dict[str, float]:
    """The pose's joint angles with ``joints`` (a mapping joint name -> degrees) overriding some of them.

    Raises :class:`UserInputError` (one line) for an unknown joint or an angle that is not a finite number
    within :data:`JOINT_RANGES_DEG`."""
    out = pose_joint_angles(pose, rest_deg)
    for name, value in dict(joints or {}).items():
        if name not in out:
            raise UserInputError(f"joint {name!r} is not known; allowed: {', '.join(JOINTS)}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise UserInputError(f"joint {name}={value!r} is not a number (degrees)") from None
        lo, hi = JOINT_RANGES_DEG[_kind(name)]
        if not (math.isfinite(v) and lo <= v <= hi):
            raise UserInputError(f"joint {name}={value!r}: expected degrees in [{lo:g}, {hi:g}]")
        out[name] = v
    return out


def parse_joints(text: str | None) -> dict[str, float]:
    """``"elbow_right=40, knee_left=15"`` -> ``{"elbow_right": 40.0, "knee_left": 15.0}`` (empty text: ``{}``);
    values are checked by :func:`resolve_joints`."""
    out: dict[str, float] = {}
    for item in (text or "").replace(";", ",").split(","):
        item = item.strip()
        if not item:
            continue
        name, sep, value = item.partition("=")
        if not sep:
            raise UserInputError(f"joints {text!r}: expected name=degrees pairs separated by commas, e.g. "
                                 "elbow_right=40,knee_left=15")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise UserInputError(f"joint {name.strip()}={value.strip()!r} is not a number (degrees)") from None
    return out


def _about(R: np.ndarray, pivot) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(pivot, dtype=np.float64)
    return R, p - R @ p


def _compose(a, b):
    """``a o b`` for affine maps ``(R, t)``."""
    return a[0] @ b[0], a[0] @ b[1] + a[1]


def bone_transforms(angles: dict[str, float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``bone -> (R [3, 3], t [3])`` (float64, body frame, units of the height) for joint ``angles``
    (degrees, every entry of :data:`JOINTS`)."""
    out = {"root": (np.eye(3), np.zeros(3))}
    for side, sign in (("right", 1.0), ("left", -1.0)):
        m = np.array([sign, 1.0, 1.0])
        shoulder = m * np.array(SHOULDER)
        elbow = shoulder - np.array([0.0, ELBOW_DROP, 0.0])
        R_sh = _rx(angles[f"shoulder_flexion_{side}"]) @ _rz(sign * angles[f"shoulder_abduction_{side}"])
        upper = _about(R_sh, shoulder)
        out[f"upper_arm_{side}"] = upper
        out[f"forearm_{side}"] = _compose(upper, _about(_rx(angles[f"elbow_{side}"]), elbow))
        thigh = _about(_rx(angles[f"hip_{side}"]), m * np.array(HIP))
        out[f"thigh_{side}"] = thigh
        out[f"shin_{side}"] = _compose(thigh, _about(_rx(-angles[f"knee_{side}"]), m * np.array(KNEE)))
    return out
