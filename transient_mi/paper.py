"""The reference experiment's settings, in one place (shared/PAPER.md).

Everything the paper fixes -- laser, SPAD/TCSPC detector, relay wall, hidden
mannequin, reconstruction volume -- is stated once here. The demo, the
experiment steps (:mod:`transient_mi.experiment`), the studies and the scene
``scenes/paper_mannequin.xml`` read it: the scene's ``<default>`` block is
written from :func:`scene_defaults` (``python -m transient_mi.paper --write-xml``;
``tests/test_paper_settings.py`` fails when the file and this module disagree).
:class:`DemoSettings` and :data:`QUICK`, what ``transient-mi demo`` and the paper scene's studies render,
detect and reconstruct, are here too (:mod:`transient_mi.demo` re-exports them).

Units: lengths in metres, times in picoseconds, rates in Hz, power in W.
"""

from __future__ import annotations

import dataclasses
import re
import sys
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class PaperSetup:
    """The paper's hardware and geometry (Infrared and Laser Engineering 47 (S1), 2018).

    Attributes
    ----------
    wavelength_nm, repetition_rate_hz
        Pulsed laser: 1550 nm at 50 MHz.
    pde
        TCSPC photon detection efficiency, 70 %.
    jitter_ps
        Timing resolution (FWHM), 25 ps.
    dark_count_rate_cps
        Dark counts, < 25 counts/s (the bound is used).
    gate_transition_ps
        Time-gated SPAD array: 120 ps gate transitions.
    tcspc_bin_width_ps, tcspc_max_count_rate_hz
        TCSPC bins of 1 ps; at most 20 M counts/s.
    wall_size_m, wall_albedo
        1 m x 1 m Lambertian relay wall (albedo 0.8, our choice: the paper states none) in z = 0.
    pixel_footprint_m, aperture_diameter_m
        Wall patch one SPAD pixel sees (1 cm: 1 cm^2 per pixel) and the collecting lens (1 inch).
    mannequin_width_m, mannequin_height_m, mannequin_distance_m, mannequin_albedo
        The 60 x 70 cm mannequin, its centre ~50 cm in front of the wall; albedo 0.5 (our choice).
    laser_origin_m, detector_origin_m
        Laser and SPAD share a position 2.2 m from the wall centre, off to the side (our choice:
        the mannequin then hides no wall patch from them).
    """

    wavelength_nm: float = 1550.0
    repetition_rate_hz: float = 50e6
    pde: float = 0.70
    jitter_ps: float = 25.0
    dark_count_rate_cps: float = 25.0
    gate_transition_ps: float = 120.0
    tcspc_bin_width_ps: float = 1.0
    tcspc_max_count_rate_hz: float = 20e6
    wall_size_m: float = 1.0
    wall_albedo: float = 0.8
    pixel_footprint_m: float = 0.01
    aperture_diameter_m: float = 0.0254
    mannequin_width_m: float = 0.60
    mannequin_height_m: float = 0.70
    mannequin_distance_m: float = 0.5
    mannequin_albedo: float = 0.5
    laser_origin_m: tuple[float, float, float] = (-2.0, 0.0, 1.0)
    detector_origin_m: tuple[float, float, float] = (-2.0, 0.0, 1.0)


#: The paper's setup.
PAPER = PaperSetup()
#: The paper scene's estimator of three-bounce light, for the scene file's default, :class:`PaperConfig`,
#: :class:`DemoSettings` and so the demo, the studies on this scene and the NLOS dataset example: the deterministic
#: quadrature (the mannequin is a mesh). At the paper's 1 ps bins and 10 ms per spot its first level
#: (:data:`PAPER_ELEMENT_SIZE_M`, :data:`PAPER_PATCH_CELLS`) states a rendering-error ratio below 0.01, where Monte
#: Carlo at the noise standard's 0.1 needed ~26k spp and reached 0.06-0.08 (bench/bench_paper_estimators.py;
#: docs/quadrature.md, "When Monte Carlo is still used"); ``estimator=monte_carlo`` renders it by sampling.
PAPER_ESTIMATOR = "quadrature"
#: The quadrature's longest element edge on the paper scene (m). The mannequin's triangles are mostly smaller (median
#: edge 9 mm), so the elements are its triangles split once (the coarse level of the error estimate is the triangles
#: themselves); a smaller value splits the long limb triangles too.
PAPER_ELEMENT_SIZE_M = 0.04
#: The quadrature's cells per pixel patch side on the paper scene: its 1 cm^2 patches are small against the 50 cm to
#: the mannequin, so one cell per patch (its tilt and convexity shift make it linear; the error estimate holds the
#: cells' part, one cell against two on the coarse elements). On the 32 x 32 array at 1 ps it states 0.0039 at 10 ms
#: (two cells: 0.0031) in 0.63 times the time of two (bench/results/paper_estimators_a32_e10ms*.json).
PAPER_PATCH_CELLS = 1
#: The quadrature's visibility refinement levels on the paper scene (the integrator's default): elements whose
#: visibility samples disagree are split in four this many times; ``render --noise-target`` adds levels where the
#: light of such elements sets the error (transient_mi.noise_target_quadrature.plan_quadrature_level).
PAPER_REFINE_LEVELS = 1
#: Array sizes compared in the paper (Fig. 4 and Fig. 5).
PAPER_ARRAY_SIZES = (4, 8, 16, 32)
#: Reconstruction volume: the wall's extent in x and y, 25 cm to 75 cm in front of it.
PAPER_BOUNDS_M = (-PAPER.wall_size_m / 2, PAPER.wall_size_m / 2, -PAPER.wall_size_m / 2, PAPER.wall_size_m / 2,
                  0.25, 0.75)


@dataclass(frozen=True)
class PaperConfig:
    """Parameters of ``scenes/paper_mannequin.xml`` that a run may change (see the scene file).

    Attributes
    ----------
    array : int
        SPAD array side (pixels); each pixel sees 1 cm^2 of wall, the array spans the 1 m wall.
    spots : int
        Laser scan grid side (spots spread over ``scan_extent_m`` of wall, default 2 x 2 over 1 m).
    scan_extent_m : float
        Side of the wall square the laser scan covers.
    distance_m, pose, rotation_deg, joints
        The mannequin: depth of its centre (m), pose, rotation about y, and joint angles overriding the
        pose's (``"elbow_right=40,knee_left=20"``, degrees; empty: the pose's own;
        :mod:`transient_mi.scenes.mannequin_skeleton`).
    power_w : float
        Laser average power (50 MHz, 1550 nm).
    spp : int
        Samples per pixel per laser spot (the demo's pilot; the scene's own default,
        :data:`SCENE_SPP`, is a quick look).
    t0_ps, n_bins, bin_width_ps
        Time axis (t = 0: the pulse leaves the laser); the paper's 1 ps TCSPC bins.
    max_depth : int
        4 = three-bounce light (the paper's model), -1 = every bounce.
    estimator : str
        ``monte_carlo`` (``spp`` samples; the default, :data:`PAPER_ESTIMATOR`) or ``quadrature`` (deterministic
        three-bounce light with a stored error estimate; ``spp`` unused unless ``max_depth`` > 4;
        docs/quadrature.md).
    element_size_m, patch_cells, refine_levels : float, int, int or None
        The quadrature's settings (None: the scene's, :data:`PAPER_ELEMENT_SIZE_M`, :data:`PAPER_PATCH_CELLS`,
        :data:`PAPER_REFINE_LEVELS`); with a noise target, where its refinement starts.
    """

    array: int = 16
    spots: int = 2
    scan_extent_m: float = PAPER.wall_size_m
    distance_m: float = PAPER.mannequin_distance_m
    pose: str = "arms_down"
    rotation_deg: float = 0.0
    joints: str = ""
    power_w: float = 0.01
    spp: int = 1024
    t0_ps: float = 12500.0
    n_bins: int = 11500
    bin_width_ps: float = PAPER.tcspc_bin_width_ps
    max_depth: int = 4
    estimator: str = PAPER_ESTIMATOR
    element_size_m: float | None = None
    patch_cells: int | None = None
    refine_levels: int | None = None

    def defines(self) -> dict[str, str]:
        """The ``-D`` values for ``scenes/paper_mannequin.xml``."""
        return {
            "array": str(self.array), "spots": str(self.spots), "scan_extent": repr(float(self.scan_extent_m)),
            "distance": repr(float(self.distance_m)), "pose": self.pose, "rotation": repr(float(self.rotation_deg)),
            "power_w": repr(float(self.power_w)), "spp": str(self.spp), "t0_ps": repr(float(self.t0_ps)),
            "n_bins": str(self.n_bins), "bin_width_ps": repr(float(self.bin_width_ps)),
            "max_depth": str(self.max_depth), "estimator": self.estimator,
            **({"joints": self.joints} if self.joints else {}),
            **({"element_size_m": repr(float(self.element_size_m))} if self.element_size_m is not None else {}),
            **({"patch_cells": str(int(self.patch_cells))} if self.patch_cells is not None else {}),
            **({"refine_levels": str(int(self.refine_levels))} if self.refine_levels is not None else {}),
        }

    def replace(self, **changes) -> "PaperConfig":
        return dataclasses.replace(self, **changes)


#: The scene file's own spp (a quick look; ``render --noise-target`` chooses the spp a budget needs).
SCENE_SPP = 128


@dataclass(frozen=True)
class DemoSettings:
    """What the demo renders, detects and reconstructs (defaults: the full run)."""

    arrays: tuple[int, ...] = PAPER_ARRAY_SIZES
    spp: int = 1024
    bin_width_ps: float = 1.0
    n_bins: int = 11500
    t0_ps: float = 12500.0
    spots: int = 2
    power_w: float = 0.01
    exposure_s: float = 0.01  # per laser spot: 5e5 pulses at 50 MHz
    voxels: tuple[int, int, int] = (64, 64, 32)
    threshold: str = "rel:0.3"
    seed: int = 0
    #: Largest ratio of rendering to photon variance (None: render as set and report the ratio); with a target,
    #: ``spp`` is the Monte Carlo pilot, or the quadrature's elements and cells are refined
    #: (transient_mi.noise_target).
    noise_target: float | None = 0.1
    #: ``monte_carlo`` (:data:`PAPER_ESTIMATOR`) or ``quadrature`` (deterministic three-bounce light; the mannequin
    #: is a mesh; ``demo --estimator quadrature``).
    estimator: str = PAPER_ESTIMATOR
    #: The target that replaces ``noise_target`` where the quadrature renders (None: ``noise_target`` for both):
    #: 0.01, as the studies' ``auto`` (issue 27: deterministic captures at a hundredth of the photon noise; Monte
    #: Carlo keeps 0.1, its samples growing as 1 / target). ``demo --noise-target R`` sets one target for both.
    quadrature_noise_target: float | None = 0.01

    def target(self) -> float | None:
        """The noise target the demo's captures are rendered to: ``quadrature_noise_target`` where the
        quadrature renders them and a target is set at all, else ``noise_target`` (None: no target)."""
        if self.noise_target is None:
            return None
        if self.estimator == "quadrature" and self.quadrature_noise_target is not None:
            return self.quadrature_noise_target
        return self.noise_target

    def config(self, array: int) -> PaperConfig:
        return PaperConfig(array=array, spots=self.spots, power_w=self.power_w, spp=self.spp,
                           t0_ps=self.t0_ps, n_bins=self.n_bins, bin_width_ps=self.bin_width_ps,
                           estimator=self.estimator)


#: ``--quick``: a first look, by Monte Carlo at 256 spp with 8 ps bins (same physics), no noise target (the ratio,
#: far above 0.1, is reported). Not the quadrature: its cost does not fall with the samples, so a quick look (the
#: array-size study's 64 x 64 array among them) would take minutes instead of seconds.
QUICK = DemoSettings(spp=256, bin_width_ps=8.0, n_bins=1438, noise_target=None, estimator="monte_carlo")


def paper_detector(**overrides):
    """The paper's detector: 70 % PDE, 25 ps FWHM jitter, < 25 cps dark counts, a gate with
    120 ps transitions opened automatically between the earliest and latest three-bounce
    arrivals from the hidden volume 25-75 cm in front of the wall (which keeps the wall's
    first-bounce return out), TCSPC limited to 20 MHz; ``overrides`` replace any field of
    :class:`spad_detector.DetectorParams`."""
    from spad_detector import DetectorParams

    base = dict(pde=PAPER.pde, jitter_ps=PAPER.jitter_ps, dark_count_rate_cps=PAPER.dark_count_rate_cps,
                gate_transition_ps=PAPER.gate_transition_ps, auto_gate=True,
                auto_gate_depth_min_m=PAPER_BOUNDS_M[4], auto_gate_depth_max_m=PAPER_BOUNDS_M[5],
                tcspc_max_count_rate_hz=PAPER.tcspc_max_count_rate_hz)
    base.update(overrides)
    return DetectorParams(**base).validate()


def _vec(v) -> str:
    return ", ".join(repr(float(c)) for c in v)


def scene_defaults() -> list[tuple[str, str]]:
    """``(name, value)`` of every ``<default>`` of ``scenes/paper_mannequin.xml``, in file order."""
    c = PaperConfig()
    return [
        ("array", str(c.array)), ("spots", str(c.spots)), ("scan_extent", repr(c.scan_extent_m)),
        ("distance", repr(c.distance_m)), ("pose", c.pose), ("rotation", repr(c.rotation_deg)),
        ("power_w", repr(c.power_w)), ("spp", str(SCENE_SPP)), ("t0_ps", repr(c.t0_ps)),
        ("n_bins", str(c.n_bins)), ("bin_width_ps", repr(c.bin_width_ps)), ("max_depth", str(c.max_depth)),
        # the estimator of three-bounce light (docs/quadrature.md): PAPER_ESTIMATOR; the quadrature's element size
        # (m), cells per patch side and visibility refinement levels on this scene (PAPER_ELEMENT_SIZE_M,
        # PAPER_PATCH_CELLS, PAPER_REFINE_LEVELS)
        ("estimator", c.estimator), ("element_size_m", repr(PAPER_ELEMENT_SIZE_M)),
        ("patch_cells", str(PAPER_PATCH_CELLS)), ("refine_levels", str(PAPER_REFINE_LEVELS)),
        ("capture", "array"), ("include_wall_return", "true"),
        ("wavelength_nm", repr(PAPER.wavelength_nm)), ("repetition_rate_hz", repr(PAPER.repetition_rate_hz)),
        ("laser_origin", _vec(PAPER.laser_origin_m)), ("detector_origin", _vec(PAPER.detector_origin_m)),
        ("pixel_footprint_m", repr(PAPER.pixel_footprint_m)), ("array_extent_m", repr(PAPER.wall_size_m)),
        ("aperture_diameter_m", repr(PAPER.aperture_diameter_m)),
        ("wall_half_size", repr(PAPER.wall_size_m / 2)), ("wall_albedo", repr(PAPER.wall_albedo)),
        ("mannequin_width", repr(PAPER.mannequin_width_m)), ("mannequin_height", repr(PAPER.mannequin_height_m)),
        ("mannequin_albedo", repr(PAPER.mannequin_albedo)), ("joints", ""),
    ]


BEGIN, END = "<!-- BEGIN generated by transient_mi/paper.py: edit it there -->", "<!-- END generated -->"


def xml_defaults_block(indent: str = "    ") -> str:
    lines = [indent + BEGIN] + [f'{indent}<default name="{k}" value="{v}"/>' for k, v in scene_defaults()]
    return "\n".join(lines + [indent + END])


def scene_file() -> Path:
    """``scenes/paper_mannequin.xml``."""
    from transient_mi.scenes import scene_path

    return scene_path("paper_mannequin")


def write_xml_defaults(path=None) -> bool:
    """Rewrite the scene's generated ``<default>`` block; returns whether the file changed."""
    path = Path(path or scene_file())
    text = path.read_text()
    pattern = re.compile(r"[ \t]*" + re.escape(BEGIN) + r".*?" + re.escape(END), re.S)
    if not pattern.search(text):
        raise ValueError(f"{path}: no generated block ({BEGIN!r} ... {END!r})")
    new = pattern.sub(lambda _m: xml_defaults_block(), text)
    if new != text:
        path.write_text(new)
    return new != text


if __name__ == "__main__":
    if sys.argv[1:] != ["--write-xml"]:
        sys.exit("usage: python -m transient_mi.paper --write-xml")
    print("changed" if write_xml_defaults() else "up to date")
