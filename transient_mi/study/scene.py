"""The scene a study renders: a shipped name or an XML path, its ``-D`` parameters and its ground truth.

For the shipped ``paper_mannequin`` scene the study knows the scene's
parameters (:class:`~transient_mi.experiment.PaperConfig`): ``-D`` values
override the study's settings (default or ``--quick``), the ground truth is the
mannequin the scene renders (pose, rotation and distance from the defines),
the reconstruction volume is the paper's (x, y in [-0.5, 0.5] m, z in
[0.25, 0.75] m) and the detector is the paper's. Any other scene is rendered
with its own defaults plus the ``-D`` values; its ground truth must be given
(a mesh or point targets, see :func:`recon.metrics.load_ground_truth`) or the
study runs without error metrics.
"""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError

#: ``-D`` names of ``scenes/paper_mannequin.xml`` -> (PaperConfig field, type).
PAPER_DEFINES = {
    "array": ("array", int), "spots": ("spots", int), "scan_extent": ("scan_extent_m", float),
    "distance": ("distance_m", float), "pose": ("pose", str), "rotation": ("rotation_deg", float),
    "power_w": ("power_w", float), "spp": ("spp", int), "t0_ps": ("t0_ps", float), "n_bins": ("n_bins", int),
    "bin_width_ps": ("bin_width_ps", float), "max_depth": ("max_depth", int), "estimator": ("estimator", str),
}
#: Samples per pixel of ``--quick`` renders of scenes other than the paper's (unless ``-D spp=`` is given).
QUICK_SPP = 64


def paper_base(quick: bool):
    """The paper scene's study settings: the demo's full settings, or ``--quick`` (8 ps bins, 256 spp)."""
    from transient_mi.paper import QUICK, DemoSettings

    s = QUICK if quick else DemoSettings()
    from transient_mi.paper import PaperConfig

    return PaperConfig(spots=s.spots, power_w=s.power_w, spp=s.spp, t0_ps=s.t0_ps, n_bins=s.n_bins,
                       bin_width_ps=s.bin_width_ps, estimator=s.estimator)


def resolve_scene_file(scene) -> Path:
    """Path of ``scene``: an existing XML file, or the name of a shipped scene (``scenes/``)."""
    from transient_mi.scenes import SCENES_DIR, shipped_scene

    if isinstance(scene, Path) or (isinstance(scene, str) and scene.strip()):
        p = Path(scene).expanduser()
        if p.is_file():
            return p.resolve()
        shipped = shipped_scene(scene)
        if shipped is not None:
            return shipped
    avail = ", ".join(sorted(q.stem for q in SCENES_DIR.glob("*.xml")))
    raise UserInputError(f"SCENE {str(scene)!r}: neither an existing file nor a shipped scene "
                         f"(shipped: {avail})")


def scene_defaults(path: Path) -> dict[str, str]:
    """The ``<default name=... value=...>`` parameters a scene file declares."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as e:
        raise UserInputError(f"SCENE {path}: not readable XML ({e})") from None
    return {d.get("name"): d.get("value") for d in root.iter("default") if d.get("name")}


def check_defines(defines) -> dict[str, str]:
    """``defines`` as a ``{name: str(value)}`` dict (a mapping, or ``None``)."""
    if defines is None:
        return {}
    if not isinstance(defines, dict):
        raise UserInputError(f"defines={defines!r}: expected a mapping of scene parameter name to value")
    out = {}
    for k, v in defines.items():
        if not isinstance(k, str) or not k.isidentifier():
            raise UserInputError(f"defines: {k!r} is not a valid scene parameter name (letters, digits, _)")
        out[k] = v if isinstance(v, str) else repr(v) if isinstance(v, float) else str(v)
    return out


@dataclass(frozen=True)
class StudyScene:
    """A resolved study scene.

    Attributes
    ----------
    name : str
        As given (shipped name or path).
    path : Path
        The XML file.
    defines : dict
        Every ``-D`` value passed to the renderer (for the paper scene, all of
        its parameters).
    spp : int
        Samples per pixel given to the renderer (0: the scene's own).
    paper : PaperConfig or None
        The paper scene's parameters (None for other scenes).
    """

    name: str
    path: Path
    defines: dict
    spp: int
    paper: object = None

    @property
    def is_paper(self) -> bool:
        return self.paper is not None

    def with_defines(self, **changes: str) -> "StudyScene":
        """A copy with some ``-D`` values changed (for the paper scene, its config too)."""
        d = dict(self.defines, **{k: str(v) for k, v in changes.items()})
        paper = self.paper
        if paper is not None:
            paper = _paper_config(paper, {k: v for k, v in changes.items()})
        return dataclasses.replace(self, defines=d, paper=paper)

    def describe(self) -> str:
        shown = ", ".join(f"{k}={v}" for k, v in sorted(self.defines.items()))
        return f"{self.path.name} ({shown})" if shown else self.path.name


def _convert(name: str, value, typ):
    text = str(value).strip()
    if typ is str:
        return text
    try:
        x = float(text)
    except ValueError:
        x = float("nan")
    if not np.isfinite(x) or (typ is int and not x.is_integer()):
        raise UserInputError(f"-D {name}={value!r}: expected {'an integer' if typ is int else 'a finite number'}")
    return int(x) if typ is int else x


def _paper_config(base, defines: dict):
    changes = {PAPER_DEFINES[k][0]: _convert(k, v, PAPER_DEFINES[k][1]) for k, v in defines.items()
               if k in PAPER_DEFINES}
    return base.replace(**changes)


def study_scene(scene, defines=None, *, quick: bool = False) -> StudyScene:
    """Resolve ``scene`` and its defines (see the module docstring)."""
    from transient_mi.paper import scene_file

    path = resolve_scene_file(scene)
    given = check_defines(defines)
    declared = scene_defaults(path)
    unknown = sorted(set(given) - set(declared))
    if unknown:
        raise UserInputError(f"-D {unknown[0]}=...: {path.name} has no parameter {unknown[0]!r} "
                             f"(it declares: {', '.join(sorted(declared)) or 'none'})")
    if path == scene_file().resolve():
        cfg = _paper_config(paper_base(quick), given)
        d = cfg.defines()
        d.update({k: v for k, v in given.items() if k not in PAPER_DEFINES})
        return StudyScene(name=str(scene), path=path, defines=d, spp=cfg.spp, paper=cfg)
    spp = 0
    if quick and "spp" not in given:
        spp = QUICK_SPP
    return StudyScene(name=str(scene), path=path, defines=given, spp=spp)


def array_size_defines(scene: StudyScene, n: int) -> dict[str, str]:
    """The ``-D`` values that make ``scene``'s SPAD array ``n x n`` pixels.

    The paper scene has ``array``; other scenes need an ``array`` parameter or
    ``width`` and ``height`` (the film's size), as the shipped NLOS scenes have.
    """
    declared = scene_defaults(scene.path)
    if "array" in declared:
        return {"array": str(n)}
    if "width" in declared and "height" in declared:
        return {"width": str(n), "height": str(n)}
    raise UserInputError(f"SCENE {scene.path.name}: has no array-size parameter; the array-size study sets "
                         "-D array=N, or -D width=N -D height=N, which the scene must declare")


def load_study_ground_truth(scene: StudyScene, ground_truth=None):
    """``(GroundTruth or None, description)`` for the study's metrics.

    ``ground_truth``: a path (mesh or point targets), a ``trimesh.Trimesh``, an
    ``(n, 3)`` array of point targets, a :class:`recon.metrics.GroundTruth`,
    or None (the paper scene's mannequin; no metrics for other scenes).
    """
    from recon.metrics import GroundTruth, load_ground_truth

    if ground_truth is None:
        if scene.is_paper:
            from transient_mi.experiment import ground_truth as mannequin

            cfg = scene.paper
            desc = (f"the rendered mannequin (pose {cfg.pose}, rotation {cfg.rotation_deg:g} deg, "
                    f"centre {cfg.distance_m:g} m from the wall)")
            return GroundTruth(mesh=mannequin(cfg), source="paper_mannequin"), desc
        return None, "none given: no error metrics (pass ground_truth / --ground-truth, a mesh or point targets)"
    if isinstance(ground_truth, GroundTruth):
        return ground_truth, str(ground_truth.source or "given")
    if isinstance(ground_truth, (str, Path)):
        gt = load_ground_truth(ground_truth)
        return gt, str(ground_truth)
    try:
        import trimesh

        if isinstance(ground_truth, trimesh.Trimesh):
            return GroundTruth(mesh=ground_truth, source="mesh"), "the given mesh"
    except ImportError:  # pragma: no cover
        pass
    pts = np.asarray(ground_truth, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or not len(pts) or not np.all(np.isfinite(pts)):
        raise UserInputError(f"ground_truth: expected a mesh or point-target file, a trimesh.Trimesh or "
                             f"(n, 3) points; got an array of shape {pts.shape}")
    return GroundTruth(points=pts, source="points"), f"{len(pts)} point target(s)"


def reconstruction_bounds(scene: StudyScene, bounds=None):
    """The voxel volume: ``bounds`` if given, the paper's for the paper scene, else None (recon's default)."""
    if bounds is not None:
        try:
            b = tuple(float(v) for v in bounds)
        except (TypeError, ValueError):
            b = ()
        if len(b) != 6 or not all(np.isfinite(b)) or not (b[0] < b[1] and b[2] < b[3] and b[4] < b[5]):
            raise UserInputError(f"bounds={bounds!r}: expected (xmin, xmax, ymin, ymax, zmin, zmax) metres "
                                 "with each min < max")
        return b
    if scene.is_paper:
        from transient_mi.paper import PAPER_BOUNDS_M

        return PAPER_BOUNDS_M
    return None


def base_detector(scene: StudyScene, detector=None):
    """The detector the study varies: ``detector``, the paper's for the paper scene, else the defaults with the
    automatic gate (docs/detector.md)."""
    from spad_detector import DetectorParams

    if detector is not None:
        if not isinstance(detector, DetectorParams):
            raise UserInputError(f"detector={detector!r}: expected a spad_detector.DetectorParams")
        return detector.validate()
    if scene.is_paper:
        from transient_mi.paper import paper_detector

        return paper_detector()
    return DetectorParams(auto_gate=True).validate()
