"""The free-mesh fit's settings (:class:`MeshSettings`), their one-line checks and the defaults that depend on
other settings or on the capture (:func:`carve_iterations`, :func:`grow_rings`, :func:`resolve_pixel_step`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from transient_core.errors import UserInputError

from .gauss_newton import pixel_step
from .mesh_carve import TV_WEIGHT
from .mesh_model import REFLECTANCES

__all__ = ["MeshSettings", "check_mesh_options", "carve_iterations", "grow_rings", "resolve_pixel_step"]

_STARTS = ("front", "closed")
#: The carving step's default iterations (:func:`carve_iterations`).
CARVE_ITERATIONS = 40
#: Rings of faces grown around the aligned start before carving, by default (:func:`grow_rings`).
GROW_RINGS = 2


@dataclass(frozen=True)
class MeshSettings:
    """Settings of the free-mesh model (units: metres; weights dimensionless, see
    :mod:`~transient_mi.fit.mesh_regularizers`)."""

    start: str = "front"  # front | closed (from the backprojection); ignored with start_mesh
    start_mesh: str | None = None  # a mesh file (e.g. a recon method's surface.ply)
    cell_m: float = 0.04  # the start mesh's resolution (halved at every later stage)
    stages: int = 2  # resolution stages (1: no subdivision)
    smoothing: float = 10.0  # lambda of the large-steps parametrisation
    laplacian: float = 1.0
    edge: float = 0.05
    normal: float = 0.1
    step_m: float = 0.003  # Adam's step per iteration at the start
    moments: str = "uniform"  # Adam's second moments of the vertices: uniform (one) or vertex (one per vertex)
    align: int = 8  # Levenberg-Marquardt iterations of the global affine map and reflectance first (0: none)
    carve: int | None = None  # per-face reflectance iterations on the aligned start, then its dark faces go
    #                           (None: CARVE_ITERATIONS with one reflectance, 0 with reflectance="face" or a
    #                           start that encloses a volume, mesh_start.encloses_volume)
    grow: int | None = None  # rings of faces cell_m wide added around the aligned start's open boundary before
    #                          carving (None: GROW_RINGS where the fit carves, else 0)
    reflectance: str = "global"  # global (one reflectance) | face (one per face, held smooth by albedo_smoothness)
    albedo_smoothness: float = 1.0  # weight of the per-face reflectance's smoothness (mesh_regularizers)
    carve_tv: float = TV_WEIGHT  # weight of the carving's total-variation prior (mesh_carve; 0: none)
    pixel_step: int | None = None  # fit every pixel_step-th pixel along each axis (CaptureModel's; 1: all;
    #                                 None: the largest keeping 8 per side, as the Gauss-Newton fit's)


def check_mesh_options(mesh: MeshSettings) -> None:
    """Refuse, in one line, a free-mesh setting out of range (the command line checks these whatever the model)."""
    if mesh.start not in _STARTS:
        raise UserInputError(f"--start {mesh.start!r} is not known; allowed: {', '.join(_STARTS)}")
    if not (isinstance(mesh.cell_m, (int, float)) and math.isfinite(mesh.cell_m) and 0.005 <= mesh.cell_m <= 0.5):
        raise UserInputError(f"cell_m={mesh.cell_m!r}: expected a length in metres from 0.005 to 0.5")
    if isinstance(mesh.stages, bool) or not isinstance(mesh.stages, (int, np.integer)) or not 1 <= mesh.stages <= 3:
        raise UserInputError(f"stages={mesh.stages!r}: expected a whole number from 1 to 3")
    if mesh.reflectance not in REFLECTANCES:
        raise UserInputError(f"--reflectance {mesh.reflectance!r} is not known; allowed: {', '.join(REFLECTANCES)}")
    for name in ("smoothing", "laplacian", "edge", "normal", "albedo_smoothness", "carve_tv"):
        v = getattr(mesh, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise UserInputError(f"{name}={v!r}: expected a finite number >= 0")
    if not (isinstance(mesh.step_m, (int, float)) and math.isfinite(mesh.step_m) and 0 < mesh.step_m <= 0.05):
        raise UserInputError(f"step_m={mesh.step_m!r}: expected a step in metres, > 0 and <= 0.05")
    if mesh.moments not in ("uniform", "vertex"):
        raise UserInputError(f"moments={mesh.moments!r}: expected uniform or vertex")
    if isinstance(mesh.align, bool) or not isinstance(mesh.align, (int, np.integer)) or not 0 <= mesh.align <= 100:
        raise UserInputError(f"align={mesh.align!r}: expected a whole number of iterations from 0 to 100")
    if mesh.carve is not None and (isinstance(mesh.carve, bool) or not isinstance(mesh.carve, (int, np.integer))
                                   or not 0 <= mesh.carve <= 200):
        raise UserInputError(f"carve={mesh.carve!r}: expected a whole number of iterations from 0 to 200")
    if mesh.grow is not None and (isinstance(mesh.grow, bool) or not isinstance(mesh.grow, (int, np.integer))
                                  or not 0 <= mesh.grow <= 4):
        raise UserInputError(f"grow={mesh.grow!r}: expected a whole number of rings from 0 to 4")
    if mesh.pixel_step is not None and (isinstance(mesh.pixel_step, bool) or not isinstance(mesh.pixel_step, (
            int, np.integer)) or not 1 <= mesh.pixel_step <= 16):
        raise UserInputError(f"pixel_step={mesh.pixel_step!r}: expected a whole number from 1 to 16")


def carve_iterations(mesh: MeshSettings) -> int:
    """The carving step's iterations: ``mesh.carve``, or by default :data:`CARVE_ITERATIONS` with one reflectance
    and none with ``reflectance="face"`` (its cut assumes one material: a darker one would be dropped). The fit also
    skips it by default when its start encloses a volume (:func:`~transient_mi.fit.mesh_start.encloses_volume`): the
    carving, made for a start that over-covers, dropped faces of midpoint-fk's closed surface of the paper mannequin
    and cost accuracy and time (docs/fit.md)."""
    if mesh.carve is not None:
        return int(mesh.carve)
    return CARVE_ITERATIONS if mesh.reflectance == "global" else 0


def grow_rings(mesh: MeshSettings) -> int:
    """The rings grown around the aligned start before carving: ``mesh.grow``, or by default :data:`GROW_RINGS`
    where the fit carves (:func:`carve_iterations`) and none where it does not (a ring nothing carves would stay)."""
    if mesh.grow is not None:
        return int(mesh.grow)
    return GROW_RINGS if carve_iterations(mesh) else 0


def resolve_pixel_step(mesh: MeshSettings, width: int, height: int) -> MeshSettings:
    """``mesh`` with its ``pixel_step`` for a ``width`` x ``height`` capture: as given (refused in one line unless it
    divides both sides), or by default the largest step that keeps
    :data:`~transient_mi.fit.gauss_newton.MIN_PIXELS` (8) pixels along each side, as the Gauss-Newton fit does: every
    fourth pixel of the paper's 32 x 32 array, every second of a 16 x 16 one. On the captures measured the scores
    held (docs/fit.md: the mannequin on 32 x 32, 16 x 16 and 8 x 8 of its 32 x 32 pixels; the letter, the tilted
    plane and the holed plate on 8 x 8 of their 16 x 16)."""
    if mesh.pixel_step is None:
        return replace(mesh, pixel_step=pixel_step(width, height))
    if width % mesh.pixel_step or height % mesh.pixel_step:
        raise UserInputError(f"--pixel-step {mesh.pixel_step}: must divide the capture's {width} x {height} pixels")
    return mesh
