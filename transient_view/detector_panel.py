"""Detector panel: what a SPAD + TCSPC would record from an ideal capture, recomputed live.

The sliders set the photon budget (laser pulses per spot), the photon
detection efficiency, the dark-count rate, the timing jitter (FWHM), the
SPAD dead time and the time gate; every change reruns the analytic engine of
:mod:`spad_detector` (the same model, budget resolution and seed
rule as ``transient-mi detect``: spot ``j`` draws from ``spot_rng(seed, j)``)
on the spot on screen. The ideal histogram of the chosen pixel (expected
photons per pulse) is drawn beside its counts, with the gate's efficiency
drawn over both.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .data import CaptureData
from .plotting import Status, image_figure, set_image

__all__ = ["DetectorPanel", "simulate_counts"]

GATE_MODES = ("no gate", "manual gate", "auto gate")


def simulate_counts(ideal_spot: np.ndarray, data: CaptureData, params, pulses: int, spot: int, seed: int = 0):
    """Counts of one spot ``[H, W, T]`` with the analytic engine, as ``transient-mi detect`` would draw them.

    Returns ``(counts[H, W, T] int64, info, params_run)`` where ``params_run`` has the gate resolved
    (``auto_gate`` turned into explicit times for this spot).
    """
    from spad_detector.budget import resolve_budget
    from spad_detector.detect import check_ideal, run_spot
    from spad_detector.gate import auto_gate
    from spad_detector.model import build_model
    from spad_detector.stream import spot_rng

    params = params.validate()
    m = data.manifest
    budget = resolve_budget(params, m.get("laser"), pulses=int(pulses))
    run = params
    if params.auto_gate:
        kw = {"spot": spot} if data.mode == "array" else {}
        g_open, g_close = auto_gate(m, params.gate_transition_ps, params.auto_gate_depth_min_m,
                                    params.auto_gate_depth_max_m, **kw)
        run = params.replace(gate_open_ps=g_open, gate_close_ps=g_close, auto_gate=False)
    H, W, T = ideal_spot.shape
    model = build_model(run, bin_width_ps=data.bin_width_ps, n_bins=T, t0_ps=data.t0_ps,
                        repetition_rate_hz=budget.repetition_rate_hz)
    arr = check_ideal(ideal_spot.reshape(H * W, T))
    if budget.photon_scale != 1.0:
        arr = arr * budget.photon_scale
    counts, info = run_spot(model, arr, budget.n_pulses, spot_rng(seed, spot), "analytic", (H, W))
    return counts.reshape(H, W, T), info, run


class DetectorPanel:
    """Bokeh layout and callbacks; ``data`` must be an ideal NLOS capture (photons per pulse)."""

    def __init__(self, data: CaptureData, doc):
        from bokeh.events import Tap
        from bokeh.layouts import column, row
        from bokeh.models import (BoxAnnotation, ColumnDataSource, DataRange1d, LinearAxis, RadioButtonGroup,
                                  Range1d, RangeSlider, Slider)
        from bokeh.plotting import figure

        from spad_detector.params import DEFAULT_PULSES, DetectorParams

        self.data, self.doc = data, doc
        d0 = DetectorParams()
        H, W, T = data.height, data.width, data.n_bins
        t0, t1 = data.t0_ps, data.t0_ps + T * data.bin_width_ps
        self.spot_j, self.py, self.px = 0, H // 2, W // 2
        self.status = Status("detector")
        self.computed = False
        self.counts = None

        self.spot_slider = Slider(start=0, end=max(data.n_files - 1, 1), value=0, step=1, title="laser spot (file)",
                                  disabled=data.n_files < 2, name="det_spot", width=250)
        self.budget = Slider(start=2, end=9, value=math.log10(DEFAULT_PULSES), step=0.1,
                             title="photon budget: log10(laser pulses per spot)", name="budget_slider", width=300,
                             css_classes=["budget-slider"])
        self.pde = Slider(start=0, end=1, value=d0.pde, step=0.01, title="PDE (photon detection efficiency)",
                          name="pde_slider", width=250)
        self.dark = Slider(start=0, end=7, value=math.log10(d0.dark_count_rate_cps), step=0.1,
                           title="dark counts: log10(counts per second)", name="dark_slider", width=250)
        self.jitter = Slider(start=0, end=500, value=d0.jitter_ps, step=5, title="jitter FWHM (ps)",
                             name="jitter_slider", width=250)
        self.dead = Slider(start=0, end=100, value=d0.dead_time_ns, step=0.5, title="SPAD dead time (ns)",
                           name="dead_slider", width=250)
        self.gate_mode = RadioButtonGroup(labels=list(GATE_MODES), active=0, name="gate_mode")
        span = t1 - t0
        self.gate = RangeSlider(start=t0, end=t1, value=(t0 + 0.25 * span, t0 + 0.75 * span),
                                step=data.bin_width_ps, title="manual gate open..close (ps)", name="gate_slider",
                                width=400)
        for w in (self.budget, self.pde, self.dark, self.jitter, self.dead, self.gate):
            w.on_change("value_throttled", lambda a, o, n: self.update())
        self.gate_mode.on_change("active", lambda a, o, n: self.update())
        self.spot_slider.on_change("value_throttled", lambda a, o, n: self._set_spot(n))

        self.f_img, self.s_img, self.m_img = image_figure(
            "counts, time-integrated (click a pixel)", "pixel x", "pixel y", (0, W, 0, H),
            tools="tap,pan,wheel_zoom,reset", colorbar_title="counts", name="counts_image")
        self.f_img.on_event(Tap, self._on_tap)
        self.marker = ColumnDataSource(data={"x": [self.px + 0.5], "y": [self.py + 0.5]})
        self.f_img.scatter("x", "y", source=self.marker, marker="square", size=10, fill_alpha=0, line_color="cyan",
                           line_width=2)
        self.ideal_src = ColumnDataSource(data={"t": [], "v": []})
        self.counts_src = ColumnDataSource(data={"t": [], "v": [], "expect": []})
        self.gate_src = ColumnDataSource(data={"t": [], "g": []})
        self.f_ideal = figure(title="ideal histogram (expected photons per pulse)", width=460, height=280,
                              x_axis_label="time (ps)", y_axis_label="photons per pulse",
                              tools="pan,wheel_zoom,box_zoom,reset", name="ideal_hist", css_classes=["tmv-ideal_hist"])
        main = self.f_ideal.line("t", "v", source=self.ideal_src, color="#2c3e50")
        self.f_ideal.y_range = DataRange1d(renderers=[main])
        self.f_counts = figure(title="counts histogram", width=460, height=280, x_axis_label="time (ps)",
                               y_axis_label="counts", tools="pan,wheel_zoom,box_zoom,reset", name="counts_hist",
                               css_classes=["tmv-counts_hist"],
                               x_range=self.f_ideal.x_range)
        bars = self.f_counts.vbar(x="t", top="v", width=data.bin_width_ps, source=self.counts_src,
                                  color="#c0392b", legend_label="counts (analytic engine)")
        self.f_counts.y_range = DataRange1d(renderers=[bars], start=0)
        for f in (self.f_ideal, self.f_counts):
            f.extra_y_ranges = {"gate": Range1d(0, 1.05)}
            f.add_layout(LinearAxis(y_range_name="gate", axis_label="gate efficiency"), "right")
            f.line("t", "g", source=self.gate_src, y_range_name="gate", color="#27ae60", line_width=2,
                   line_dash="dashed", legend_label="gate")
            f.legend.location = "top_right"
            f.legend.label_text_font_size = "9px"
        self.gate_box = [BoxAnnotation(fill_color="#27ae60", fill_alpha=0.08, visible=False) for _ in range(2)]
        self.f_ideal.add_layout(self.gate_box[0])
        self.f_counts.add_layout(self.gate_box[1])

        controls = column(self.budget, self.pde, self.dark, self.jitter, self.dead, self.gate_mode, self.gate,
                          self.spot_slider)
        self.layout = column(row(controls, self.f_img), row(self.f_ideal, self.f_counts), self.status.div)

    # ---------------------------------------------------------------- model

    def params(self):
        from spad_detector.params import DetectorParams

        mode = GATE_MODES[self.gate_mode.active]
        gate = {}
        if mode == "manual gate":
            gate = dict(gate_open_ps=float(self.gate.value[0]), gate_close_ps=float(self.gate.value[1]))
        elif mode == "auto gate":
            gate = dict(auto_gate=True)
        return DetectorParams(pde=float(self.pde.value), dark_count_rate_cps=float(10 ** self.dark.value),
                              jitter_ps=float(self.jitter.value), dead_time_ns=float(self.dead.value), **gate)

    @property
    def pulses(self) -> int:
        return int(round(10 ** self.budget.value))

    def update(self) -> None:
        """Recompute the counts of the spot on screen and redraw (timed, reported in the status line)."""
        from transient_core.errors import UserInputError

        from spad_detector.gate import gate_efficiency

        t_start, cpu_start = time.perf_counter(), time.process_time()
        try:
            ideal = self.data.spot(self.spot_j)
            counts, info, run = simulate_counts(ideal, self.data, self.params(), self.pulses, self.spot_j)
        except UserInputError as e:
            self.status.error(str(e))
            return
        self.counts, self.computed = counts, True
        d = self.data
        t = d.times_ps
        g = gate_efficiency(t, run.gate_open_ps, run.gate_close_ps, run.gate_transition_ps)
        self.gate_src.data = {"t": t, "g": np.broadcast_to(g, t.shape).astype(np.float64)}
        for box in self.gate_box:
            box.visible = run.gate_open_ps is not None
            if run.gate_open_ps is not None:
                box.left, box.right = float(run.gate_open_ps), float(run.gate_close_ps)
        set_image(self.s_img, self.m_img, counts.sum(axis=-1).astype(np.float64), low=0.0)
        self._update_pixel()
        ms = 1e3 * (time.perf_counter() - t_start)
        cpu_ms = 1e3 * (time.process_time() - cpu_start)  # all threads of the server process
        exact = "exact" if info.get("exact") else "approximate"
        self.status.done(f"{self.pulses:.3g} pulses, spot {self.spot_j}: {int(counts.sum()):,} counts in the spot; "
                         f"engine analytic ({exact}), {ms:.0f} ms ({cpu_ms:.0f} ms CPU)")

    def _update_pixel(self) -> None:
        if self.counts is None:
            return
        d = self.data
        ideal = d.spot(self.spot_j)[self.py, self.px].astype(np.float64)
        c = self.counts[self.py, self.px].astype(np.float64)
        self.ideal_src.data = {"t": d.times_ps, "v": ideal}
        self.counts_src.data = {"t": d.times_ps, "v": c, "expect": c}
        self.f_counts.title.text = f"counts of pixel (y={self.py}, x={self.px}): {int(c.sum()):,}"
        self.f_ideal.title.text = (f"ideal histogram of pixel (y={self.py}, x={self.px}): "
                                   f"{ideal.sum():.3g} photons per pulse")
        self.marker.data = {"x": [self.px + 0.5], "y": [self.py + 0.5]}

    def _on_tap(self, event) -> None:
        x, y = int(np.floor(event.x)), int(np.floor(event.y))
        if 0 <= x < self.data.width and 0 <= y < self.data.height:
            self.px, self.py = x, y
            self._update_pixel()
            self.status.done(f"pixel ({y}, {x})")

    def _set_spot(self, j: int) -> None:
        self.spot_j = int(j)
        self.update()


def unavailable_layout(message: str):
    """The detector tab for data it cannot simulate (counts without their ideal capture, camera captures)."""
    from bokeh.models import Div

    return Div(text=f"<p style='font-size:14px'>{message}</p>", name="detector_unavailable", width=700)
