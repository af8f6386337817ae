"""The forward model a fit compares with a counts capture: render a model mesh in the capture's own scene,
pass it through the capture's detector, and score it against the detected counts.

A counts capture's manifest names its scene file, the ``-D`` values it was rendered with, the detector
and its photon budget (``render`` and ``detector`` entries). :class:`CaptureModel` loads that scene
again, removes its hidden objects (every shape but the relay wall) and puts one triangle mesh in their
place whose vertex positions and reflectance the fit sets (``set_mesh``); relay wall, laser, SPAD array
and detector stay the capture's.

Time axis and temporal blur
---------------------------
The counts are summed into bins of ``bin_width_ps`` (an integer multiple of the capture's: the sum of
Poisson counts is Poisson, so nothing is lost but sub-bin timing). The renderer carries the arrival-time
derivative through its continuous Gaussian kernel (the film's ``kernel_sigma_ps``, see
``docs/differentiable.md``), so the detector's timing jitter is applied there instead of in the detector
layer, and the counts are blurred by the rest, ``sqrt(sigma^2 - sigma_jitter^2)``, so that model and
data are always blurred alike (:meth:`CaptureModel.counts_blurred`). The optimiser renders at one
``sigma`` (its final blur) and reaches coarser ones by convolving the expected counts
(:meth:`CaptureModel.blur`).

Objective
---------
The weighted squared difference ``0.5 sum w (mu - k)^2`` over spots, pixels and bins (``mu``: expected
counts, ``k``: counts, both blurred alike) with weights ``w = 1 / (k + k_floor)`` that depend on the data
only: ``k_floor`` is the mean count of the bins holding counts. Near ``mu = k`` and where counts are
many this is the Gaussian approximation of the Poisson negative log-likelihood (``w = 1/k``); the floor
keeps light the model puts where no counts are from dominating (the Poisson cost there grows linearly,
``1/(k + 1)`` weights would make it quadratic and heavy, and the reflectance then absorbs any misfit).
Its minimum is ``mu = k`` whatever the weights, so a model that can reproduce the counts is fitted
without bias. The Poisson NLL itself is reported (:meth:`CaptureModel.poisson_nll`) but not descended:
with a Monte Carlo ``mu`` its gradient ``1 - k / mu`` is biased (Jensen) and unbounded where a bin
happens to get no sample; so is every objective whose weights depend on ``mu``. The gradient
``w (mu_a - k) dmu_b`` with ``mu_a`` and ``dmu_b`` from independent renders (different seeds) is an
unbiased estimate of the objective's gradient.
"""

from __future__ import annotations

import math
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_core.errors import UserInputError
from transient_core.stack import read_manifest, read_spot

from transient_mi._upload import upload

__all__ = ["CaptureModel"]

#: The quadrature's settings of the models' fits (``mannequin``, ``patches``: :func:`~transient_mi.fit.api.fit_capture`):
#: one cell per pixel patch side (the paper scene's own captures use one) and the fine level only (a fit reads no
#: error estimate, whose levels, the coarse elements and with one cell the cells' level, cost as much as the result:
#: :func:`~transient_mi.integrators._nlos_quadrature.error_estimate`). The free-mesh fit keeps the defaults (2 cells,
#: the estimate's levels integrated).
FIT_QUADRATURE = {"patch_cells": 1, "error_estimate": False}


def fit_bin_factor(bin_width_ps: float, capture_bin_width_ps: float, n_bins: int) -> int | None:
    """How many of the capture's bins (``capture_bin_width_ps`` wide, ``n_bins`` of them) one of the fit's bins
    (``bin_width_ps``) sums; None unless that is a whole number >= 1 that divides ``n_bins``."""
    factor = float(bin_width_ps) / float(capture_bin_width_ps)
    if not (math.isfinite(factor) and factor >= 1 and abs(factor - round(factor)) < 1e-9
            and int(n_bins) % int(round(factor)) == 0):
        return None
    return int(round(factor))


def _blur_time(x: np.ndarray, sigma_bins: float) -> np.ndarray:
    if sigma_bins <= 1e-3:
        return x
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(x, sigma_bins, axis=-1, mode="constant", truncate=4.0)


#: The model mesh's face attribute holding a per-face reflectance (``reflectance="face"``).
FACE_REFLECTANCE = "face_reflectance"


class CaptureModel:
    """A counts capture and the forward model that fits it.

    Parameters
    ----------
    capture_dir : path
        A counts capture (``transient-mi detect`` or ``demo`` output) whose manifest records the scene it
        was rendered from (``array`` or ``confocal``).
    n_faces, n_vertices : int
        Size of the model mesh (fixed for the fit).
    bin_width_ps : float
        The fit's time bins, ps; an integer multiple of the capture's that divides its number of bins
        (default 10 ps).
    estimator, element_size_m : str, float
        ``auto`` (the quadrature where the scene allows it), ``quadrature`` or ``monte_carlo`` (whatever estimator
        rendered the capture); the quadrature's element size, m.
    patch_cells, error_estimate : int, bool
        The quadrature's cells per pixel patch side, and whether its renders integrate the error estimate's levels
        (:data:`FIT_QUADRATURE`: the models' fits' choice).
    pixel_step : int
        Fit every ``pixel_step``-th pixel along each axis (pixel ``pixel_step * j + pixel_offset``; the others are not
        rendered or compared; 1: all). ``width``, ``height`` and ``counts`` are then those of the pixels kept.
    counts : numpy.ndarray, optional
        The capture's counts already summed into the fit's bins, ``[G, H, W, T]`` (the capture's pixels; default:
        read from ``capture_dir``).
    reflectance : str
        ``global``: one diffuse reflectance for the model mesh; ``face``: one per face (the mesh's face attribute
        ``face_reflectance`` through a ``mesh_attribute`` texture; :meth:`set_mesh` takes ``[F]`` values and
        :meth:`backward` returns ``[F]`` derivatives).

    Attributes
    ----------
    counts : numpy.ndarray
        ``[G, P, T]`` float64 counts summed into the fit's bins (``G`` spots, ``P = height * width`` pixels,
        row-major, ``T`` bins).
    """

    def __init__(self, capture_dir, faces: np.ndarray, n_vertices: int, *, bin_width_ps: float = 10.0,
                 albedo=0.5, estimator: str = "auto", element_size_m: float = 0.03,
                 dead_time: str = "first_order", patch_cells: int = 2, error_estimate: bool = True,
                 reflectance: str = "global", pixel_step: int = 1, counts: np.ndarray | None = None):
        self.capture_dir = Path(capture_dir)
        if not (isinstance(pixel_step, (int, np.integer)) and 1 <= pixel_step <= 16):
            raise ValueError(f"pixel_step={pixel_step!r}: expected a whole number from 1 to 16")
        self.pixel_step = int(pixel_step)
        if dead_time not in ("first_order", "renewal"):
            raise ValueError(f"dead_time={dead_time!r}: expected first_order or renewal")
        #: ``first_order``: the factor of :meth:`dead_time_factor`, held constant in the gradient (the model fits);
        #: ``renewal``: the detector's whole-blind-cycles mean and its full derivative
        #: (:class:`~spad_detector.likelihood.RenewalExpectedCounts`; the free-mesh fit).
        self.dead_time = dead_time
        if reflectance not in ("global", "face"):
            raise ValueError(f"reflectance={reflectance!r}: expected global or face")
        self.reflectance = reflectance
        m = read_manifest(self.capture_dir)
        if m.get("kind") != "counts":
            raise UserInputError(f"capture {str(self.capture_dir)!r} holds {m.get('kind')!r} data; fit needs a "
                                 "counts capture (transient-mi detect, or the demo's captures/array_NN/counts)")
        if m.get("capture") not in ("array", "confocal"):
            raise UserInputError(f"capture {str(self.capture_dir)!r} is a {m.get('capture')!r} capture; fit needs an "
                                 "NLOS capture (array or confocal)")
        render = m.get("render") or {}
        scene_file = render.get("scene_file")
        if not scene_file or not Path(scene_file).is_file():
            raise UserInputError(f"capture {str(self.capture_dir)!r}: its scene file {scene_file!r} is not there; fit "
                                 "renders the capture's own scene (relay wall, laser, SPAD array) again")
        self.manifest = m
        t = m["time"]
        factor = fit_bin_factor(bin_width_ps, t["bin_width_ps"], t["n_bins"])
        if factor is None:
            raise UserInputError(
                f"bin_width_ps={bin_width_ps!r}: must be a whole multiple of the capture's {t['bin_width_ps']:g} ps "
                f"that divides its {t['n_bins']} bins")
        self.factor = factor
        self.bin_width_ps = float(bin_width_ps)
        self.t0_ps = float(t["t0_ps"])
        self.n_bins = int(t["n_bins"]) // self.factor
        width, height = int(m["width"]), int(m["height"])
        s = self.pixel_step
        if width % s or height % s:
            raise ValueError(f"pixel_step={s}: must divide the capture's {width} x {height} pixels")
        #: Index of the pixel each ``pixel_step`` x ``pixel_step`` block keeps (the same along x and y).
        self.pixel_offset = (s - 1) // 2
        self.width, self.height = width // s, height // s
        self.n_spots = int(m.get("n_files", 1))
        G, P, T = self.n_spots, self.width * self.height, self.n_bins
        o = self.pixel_offset
        given = counts
        if given is not None and np.shape(given) != (G, height, width, T):
            raise ValueError(f"counts of shape {np.shape(given)}: expected {(G, height, width, T)} (the capture's in "
                             "the fit's bins)")
        counts = np.zeros((G, P, T))
        for g in range(G):
            if given is not None:
                counts[g] = np.asarray(given[g], dtype=np.float64)[o::s, o::s].reshape(P, T)
                continue
            c = read_spot(self.capture_dir, g, m).astype(np.float64).reshape(height, width, -1)[o::s, o::s]
            counts[g] = c.reshape(P, T, self.factor).sum(axis=-1)
        self.counts = counts
        held = counts[counts >= 1]
        #: Mean count of the bins that hold at least one count (the objective's weight floor).
        self.k_floor = float(held.mean()) if held.size else 1.0
        self._detector_setup(m)
        self._scene_setup(render, faces, n_vertices, albedo)
        self._choose_estimator(estimator, element_size_m, int(patch_cells), bool(error_estimate))
        self._blurred = {}
        self._probs = None
        self._keep = None
        from transient_mi._visibility_memo import VisibilityMemo

        #: The quadrature's visibility masks of the mesh last rendered (:meth:`_held_geometry`).
        self.visibility = VisibilityMemo()

    # --- detector ---------------------------------------------------------------------------------------

    def _detector_setup(self, m: dict) -> None:
        from spad_detector.likelihood import ExpectedCounts, RenewalExpectedCounts
        from spad_detector.model import build_model
        from spad_detector.params import DetectorParams

        det = dict(m["detector"])
        resolved = det.get("resolved") or {}
        pulses = det.get("pulses")
        keep = {k: v for k, v in det.items() if k not in ("resolved", "pulses", "exposure_s", "pulses_requested",
                                                            "exposure_s_requested", "seed", "engine",
                                                            "model", "model_version")}
        params = DetectorParams.from_dict(keep)
        self.jitter_sigma_ps = float(params.jitter_sigma_ps)
        opens = resolved.get("gate_open_ps_per_spot") or [resolved.get("gate_open_ps")] * self.n_spots
        closes = resolved.get("gate_close_ps_per_spot") or [resolved.get("gate_close_ps")] * self.n_spots
        self.layers = []
        for g in range(self.n_spots):
            p = params.replace(auto_gate=False, gate_open_ps=opens[g], gate_close_ps=closes[g], jitter_ps=0.0,
                               irf_tail_fraction=0.0)
            model = build_model(p, bin_width_ps=self.bin_width_ps, n_bins=self.n_bins, t0_ps=self.t0_ps,
                                repetition_rate_hz=resolved.get("repetition_rate_hz"))
            layer = RenewalExpectedCounts if self.dead_time == "renewal" else ExpectedCounts
            self.layers.append(layer(model, int(pulses)))
        self.detector = params

    def dead_time_factor(self, ideal: np.ndarray) -> np.ndarray:
        """``[G, P, 1]`` share of cycles in which the detector is ready: ``1 / (1 + p D)``, with ``p`` a pixel's
        probability of an event per cycle and ``D`` the dead time in laser periods beyond the first
        (nonparalyzable, SPAD or TCSPC, whichever is longer).

        :class:`~spad_detector.likelihood.ExpectedCounts` is exact when the detector is ready at each cycle's
        start; the paper's TCSPC dead time (50 ns at a 20 ns laser period) spans 2.5 periods, ``D = 1.5`` beyond
        the cycle of the event, which removes about ``D p`` of the counts (without the factor the model
        overestimates the demo's counts by 3.7 %, with it by 0.9 %). The fit treats the factor as a constant in the gradient (its own derivative
        changes the gradient by a relative ``p D``, a few per cent).

        With ``dead_time="renewal"`` the layers hold the dead time themselves (the detector's whole blind cycles,
        ``m = 2`` for the paper's TCSPC behind a gate under 10 ns wide, where ``D = 1.5`` would overestimate a
        saturated pixel's counts by up to 20 %), and this factor is 1."""
        if self.dead_time == "renewal":
            return np.ones((ideal.shape[0], ideal.shape[1], 1))
        m = self.layers[0].model
        D = max(m.spad_dead_time_ps, m.tcspc_dead_time_ps) / m.grid.period_ps - 1.0
        if D <= 0:
            return np.ones((ideal.shape[0], ideal.shape[1], 1))
        return np.stack([1.0 / (1.0 + p.sum(axis=-1, keepdims=True) * D) for _, _, p in self._probabilities(ideal)])

    def _probabilities(self, ideal: np.ndarray) -> list:
        """Per spot, the detector layer's :meth:`~spad_detector.likelihood.ExpectedCounts.probabilities` of
        ``ideal [G, P, T]``, kept for the last ``ideal`` array (by identity: one iteration's dead-time factor,
        expected counts and derivative share them; an ideal capture is never changed in place here). On the demo's
        32 x 32 capture they were made three times an iteration, about 0.3 s of it."""
        if self._probs is None or self._probs[0] is not ideal:
            self._probs = None  # (the last ones freed first)
            self._probs = (ideal, [self.layers[g].probabilities(ideal[g]) for g in range(self.n_spots)])
        return self._probs[1]

    def expected_counts(self, ideal: np.ndarray, factor: np.ndarray | None = None) -> np.ndarray:
        """``[G, P, T]`` expected counts of an ideal capture (photons per pulse) in the fit's bins."""
        f = self.dead_time_factor(ideal) if factor is None else factor
        pr = self._probabilities(ideal)
        return np.stack([self.layers[g](ideal[g], pr[g]) for g in range(self.n_spots)]) * f

    def _blurred_entry(self, sigma_ps: float) -> tuple:
        """``(counts blurred to sigma_ps, their weights)``, made once per blur and kept for two blurs (the fixed end
        blur and the current one)."""
        key = round(float(sigma_ps), 6)
        if key not in self._blurred:
            extra = math.sqrt(max(sigma_ps ** 2 - self.jitter_sigma_ps ** 2, 0.0)) / self.bin_width_ps
            if len(self._blurred) >= 2:
                self._blurred.pop(next(k for k in self._blurred if k != self._keep))
            k = _blur_time(self.counts, extra)
            self._blurred[key] = (k, 1.0 / (k + self.k_floor))
        return self._blurred[key]

    def counts_blurred(self, sigma_ps: float) -> np.ndarray:
        """The counts blurred to a total temporal spread ``sigma_ps`` (>= the jitter's)."""
        return self._blurred_entry(sigma_ps)[0]

    def keep_blur(self, sigma_ps: float) -> None:
        """Keep the counts blurred to ``sigma_ps`` cached (the blur every iteration also evaluates)."""
        self._keep = round(float(sigma_ps), 6)

    def blur(self, x: np.ndarray, from_ps: float, to_ps: float) -> np.ndarray:
        """``x [..., T]`` (a render or expected counts at temporal spread ``from_ps``) blurred to ``to_ps``."""
        return _blur_time(x, math.sqrt(max(to_ps ** 2 - from_ps ** 2, 0.0)) / self.bin_width_ps)

    # --- scene ------------------------------------------------------------------------------------------

    def _scene_setup(self, render: dict, faces: np.ndarray, n_vertices: int, albedo: float) -> None:
        from transient_mi.scene_io import load_scene

        defines = dict(render.get("defines") or {})
        defines.update({"n_bins": str(self.n_bins), "bin_width_ps": repr(self.bin_width_ps),
                        "t0_ps": repr(self.t0_ps), "max_depth": "4"})
        src = load_scene(render["scene_file"], defines)
        sensor = src.sensors()[0]
        if not hasattr(sensor, "nlos_setup"):
            raise UserInputError(f"capture {str(self.capture_dir)!r}: its scene has no spad_array sensor")
        from transient_mi.sensors._nlos_setup import RELAY_WALL_ID

        wall = [s for s in src.shapes() if s.id() == RELAY_WALL_ID]
        if self.pixel_step > 1:
            sensor = self._subsampled_sensor(sensor)
        if not wall:
            raise UserInputError(f"capture {str(self.capture_dir)!r}: its scene has no shape with id {RELAY_WALL_ID}")
        self.mesh = mi.Mesh("model", int(n_vertices), len(faces), has_vertex_normals=False,
                            props=self._mesh_props(albedo, self.reflectance))
        if self.reflectance == "face":
            self.mesh.add_attribute(FACE_REFLECTANCE, 1, np.broadcast_to(
                np.asarray(albedo, dtype=np.float64).ravel(), (len(faces),)).astype(np.float32).tolist())
        mp = mi.traverse(self.mesh)
        mp["faces"] = upload(mi.UInt32, faces)
        mp["vertex_positions"] = dr.zeros(mi.Float, 3 * int(n_vertices))
        mp.update()
        scene_dict = {"type": "scene", "integrator": src.integrator(), "sensor": sensor, "relay_wall": wall[0],
                      "model": self.mesh}
        for k, e in enumerate(src.emitters()):
            scene_dict[f"emitter_{k}"] = e
        self.scene = mi.load_dict(scene_dict)
        del src
        self.sensor = self.scene.sensors()[0]
        self.integrator = self.scene.integrator()
        self.integrator.nlos_options["hidden_geometry_prob"] = 1.0
        self.params = mi.traverse(self.scene)
        self.vkey = "model.vertex_positions"
        self.rkey = (f"model.{FACE_REFLECTANCE}" if self.reflectance == "face" else
                     [k for k in self.params.keys() if k.startswith("model.bsdf.reflectance")][0])
        self.spots = list(range(self.n_spots)) if self.manifest["capture"] == "array" else [0]

    def _subsampled_sensor(self, sensor):
        """A ``spad_array`` of every ``pixel_step``-th pixel of ``sensor`` (pixel ``(s j + o, s i + o)`` of the
        capture, ``o = pixel_offset``): the same footprints, detector, aperture and options, ``pixel_step`` times
        the pitch; its grid's centre moved in the wall plane so that its patches are the capture's own (the
        ``target``, at which the aperture points, kept). What it renders is those pixels of the capture exactly."""
        from transient_mi.wall import WallFrame

        f, s = sensor.film(), self.pixel_step
        if f.spectral_bands_nm:
            raise UserInputError(f"capture {str(self.capture_dir)!r}: a fit on every {s}th pixel of a capture with "
                                 "spectral bands is not supported")
        film = {"type": "transient_film", "width": self.width, "height": self.height, "n_bins": int(f.n_bins),
                "bin_width_ps": float(f.bin_width_ps), "t0_ps": float(f.t0_ps),
                "kernel_sigma_ps": float(f.kernel_sigma_ps)}
        pt = lambda a: mi.ScalarPoint3f(*map(float, a))  # noqa: E731
        new = mi.load_dict({
            "type": "spad_array", "origin": pt(sensor.origin), "target": pt(sensor.target),
            "wall_normal": mi.ScalarVector3f(*map(float, sensor.frame.normal)),
            "pixel_footprint_m": float(sensor.pixel_footprint_m), "pixel_pitch_m": s * float(sensor.pixel_pitch_m),
            "aperture_diameter_m": float(sensor.aperture_diameter_m), "capture": sensor.capture,
            "include_first_last": bool(sensor.include_first_last),
            "include_wall_return": bool(sensor.include_wall_return), "pixel_sampling": sensor.pixel_sampling,
            "film": film, "sampler": {"type": "independent", "sample_count": 1}})
        shift = (self.pixel_offset - 0.5 * (s - 1)) * float(sensor.pixel_pitch_m)
        fr = sensor.frame
        new.frame = WallFrame(fr.origin + shift * (fr.ex + fr.ey), fr.normal, fr.ex, fr.ey)
        return new

    def _choose_estimator(self, requested: str, element_size_m: float, patch_cells: int,
                          error_estimate: bool) -> None:
        """``estimator``: ``quadrature`` where the capture's scene allows it (meshes, a planar relay wall, no
        windows, media or beam divergence: :func:`~transient_mi.integrators._nlos_quadrature.check_supported`),
        else ``monte_carlo``; ``estimator_reason`` says why not (None when it is the quadrature or was asked
        for)."""
        from transient_mi.integrators._nlos_quadrature import check_supported
        from transient_mi.props import PluginParameterError

        if requested not in ("auto", "quadrature", "monte_carlo"):
            raise UserInputError(f"estimator={requested!r}: expected auto, quadrature or monte_carlo")
        if not (isinstance(element_size_m, (int, float)) and 0.002 <= element_size_m <= 0.5):
            raise UserInputError(f"element_size_m={element_size_m!r}: expected a length in metres from 0.002 to 0.5")
        why = None
        if requested != "monte_carlo":
            if self.sensor.get_medium() is not None:
                why = "the detector sees the wall through a medium"
            else:
                try:
                    check_supported(self.sensor.nlos_setup(self.scene), {"max_depth": 4}, "fit")
                except PluginParameterError as e:
                    why = str(e).split("capture: ", 1)[-1].split("; use", 1)[0]
            if why is not None and requested == "quadrature":
                raise UserInputError(f"estimator=quadrature: the capture's scene cannot be rendered by it: {why}")
        self.estimator = "monte_carlo" if requested == "monte_carlo" or why else "quadrature"
        self.estimator_reason = why
        self.element_size_m = float(element_size_m)
        if self.estimator == "monte_carlo":
            # (the capture's own scene may have been rendered by the quadrature: the paper scene's default)
            self.integrator.nlos_options["estimator"] = "monte_carlo"
        else:
            self.integrator.nlos_options.update(estimator="quadrature", element_size_m=self.element_size_m,
                                                patch_cells=patch_cells, refine_levels=1,
                                                error_estimate=error_estimate, pair_refinement=False)

    def set_element_size(self, element_size_m: float) -> None:
        """The quadrature's element size for the next renders (coarse to fine; no effect with Monte Carlo)."""
        if self.estimator == "quadrature":
            self.integrator.nlos_options["element_size_m"] = float(element_size_m)

    @staticmethod
    def _mesh_props(albedo, reflectance: str = "global") -> mi.Properties:
        props = mi.Properties()
        tex = ({"type": "mesh_attribute", "name": FACE_REFLECTANCE} if reflectance == "face" else
               {"type": "rgb", "value": float(albedo)})
        props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": tex})
        return props

    def set_mesh(self, vertices: np.ndarray, albedo) -> None:
        """Model mesh vertices ``[V, 3]`` (metres, world frame) and reflectance (a float; with
        ``reflectance="face"`` a float for every face or ``[F]``)."""
        self.params[self.vkey] = upload(mi.Float, vertices)
        if self.reflectance == "face":
            n = dr.width(self.params[self.rkey])
            self.params[self.rkey] = upload(mi.Float, np.broadcast_to(np.ravel(albedo), (n,)))
        else:
            self.params[self.rkey] = type(self.params[self.rkey])(float(albedo))
        self.params.update()

    def _set_sigma(self, sigma_ps: float) -> None:
        self.sensor.film().kernel_sigma_ps = float(sigma_ps)

    def _held_geometry(self):
        """The visibility memo active for the vertices the scene holds now (a context; this model owns its scene and
        moves only them: :mod:`~transient_mi._visibility_memo`)."""
        self.visibility.set_geometry(np.asarray(dr.detach(self.params[self.vkey])))
        return self.visibility.active()

    def _render(self, seed: int, spp: int) -> np.ndarray:
        # the mesh moved: the sensor's cached scene analysis (hidden shapes' total area) is rebuilt
        self.sensor.forget_nlos_setup()
        with self._held_geometry():
            res = self.integrator.render_transient(self.scene, self.sensor, seed=int(seed), spp=int(spp),
                                                   spots=self.spots)
        return np.stack([np.asarray(r.histogram, dtype=np.float64).reshape(self.width * self.height, self.n_bins)
                         for r in res])

    def ideal(self, seed: int, spp: int, sigma_ps: float) -> np.ndarray:
        """``[G, P, T]`` ideal capture (photons per pulse) of the current mesh: its three-bounce light and the
        relay wall's direct return (closed form, as in the capture)."""
        self._set_sigma(sigma_ps)
        return self._render(seed, spp)

    def weights(self, sigma_ps: float) -> np.ndarray:
        """``1 / (k + k_floor)`` per bin (see the module docstring), made with the blurred counts ``k`` (an iteration
        asks for the weights of two blurs twice each)."""
        return self._blurred_entry(sigma_ps)[1]

    def objective(self, mu: np.ndarray, sigma_ps: float) -> tuple[float, np.ndarray]:
        """Objective ``0.5 sum w (mu - k)^2`` and its gradient ``w (mu - k)`` with respect to ``mu``."""
        k = self.counts_blurred(sigma_ps)
        r = (mu - k) * self.weights(sigma_ps)
        return 0.5 * float(np.sum((mu - k) * r)), r

    def poisson_nll(self, mu: np.ndarray) -> float:
        """Poisson negative log-likelihood of the (unblurred) counts for means ``mu`` (floored at 1e-12)."""
        from spad_detector.likelihood import poisson_nll

        return poisson_nll(np.maximum(mu, 1e-12), self.counts)

    def backward(self, grad_mu: np.ndarray, ideal_ref: np.ndarray, seed: int, spp: int,
                 sigma_ps: float, factor: np.ndarray | None = None, vertices: bool = True) -> tuple[np.ndarray, float]:
        """Gradient of ``<grad_mu, mu>`` with respect to the mesh vertices ``[V, 3]`` and the reflectance (a float;
        ``[F]`` with ``reflectance="face"``).

        ``ideal_ref`` is the ideal capture the detector layer is linearised at (pile-up; ``factor``: its
        :meth:`dead_time_factor`, if already computed); the render runs with ``seed`` (use one independent of
        the render that gave ``grad_mu``). ``vertices=False``: the reflectance's alone (no geometry derivative
        pass; the vertices' gradient is zeros)."""
        from transient_mi.integrators._nlos_ad import nlos_backward

        f = self.dead_time_factor(ideal_ref) if factor is None else factor
        pr = self._probabilities(ideal_ref)
        g_ideal = np.stack([self.layers[g].vjp(ideal_ref[g], grad_mu[g] * f[g], pr[g]) for g in range(self.n_spots)])
        self._set_sigma(sigma_ps)
        v, r = self.params[self.vkey], self.params[self.rkey]
        if vertices:
            dr.enable_grad(v)
        dr.enable_grad(r)
        self.params.update()
        shape = (len(self.spots), self.height, self.width, self.n_bins) if len(self.spots) > 1 \
            else (self.height, self.width, self.n_bins)
        try:
            if self.estimator == "quadrature":  # (deterministic: no seed, no samples)
                from transient_mi.integrators._nlos_quadrature_ad import quadrature_backward

                self.sensor.forget_nlos_setup()
                with self._held_geometry():
                    quadrature_backward(self.integrator, self.scene, self.params, g_ideal.reshape(shape),
                                        self.sensor, spots=self.spots)
            else:
                nlos_backward(self.integrator, self.scene, self.params, g_ideal.astype(np.float32).reshape(shape),
                              self.sensor, int(seed), int(spp), spots=self.spots)
            gv = (np.asarray(dr.grad(self.params[self.vkey]), dtype=np.float64).reshape(-1, 3) if vertices
                  else np.zeros((dr.width(self.params[self.vkey]) // 3, 3)))
            gr_all = np.asarray(dr.grad(self.params[self.rkey]), dtype=np.float64)
            gr = gr_all.ravel().copy() if self.reflectance == "face" else float(np.sum(gr_all))
        finally:
            dr.disable_grad(self.params[self.vkey])
            dr.disable_grad(self.params[self.rkey])
            self.params[self.vkey] = dr.detach(self.params[self.vkey])
            self.params[self.rkey] = dr.detach(self.params[self.rkey])
            self.params.update()
        return gv, gr
