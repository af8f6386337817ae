"""Capture panel: time-integrated image per laser spot, a time slider (with play), x-t and y-t streak
images, the histogram of a clicked pixel (linear or log), the wall with its laser spots and pixel
patches, and the manifest facts.

Images show pixel columns (x) left to right and rows (y) bottom to top, so pixel (0, 0), the wall patch
with the smallest wall coordinates, is at the bottom left, as on the wall.
"""

from __future__ import annotations

import numpy as np

from .data import CaptureData
from .plotting import Status, facts_html, image_figure, robust_max, set_image

__all__ = ["CapturePanel"]

PLAY_PERIOD_MS = 120


class CapturePanel:
    """Bokeh layout and callbacks for one :class:`~transient_view.data.CaptureData`."""

    def __init__(self, data: CaptureData, doc):
        from bokeh.events import Tap
        from bokeh.layouts import column, row
        from bokeh.models import (Button, ColumnDataSource, Div, RadioButtonGroup, Slider, Span)
        from bokeh.plotting import figure

        self.data, self.doc = data, doc
        H, W, T = data.height, data.width, data.n_bins
        self.spot_j, self.t_bin, self.py, self.px = 0, 0, H // 2, W // 2
        self._play_cb = None
        self.status = Status("capture")
        t0, t1 = data.t0_ps, data.t0_ps + T * data.bin_width_ps
        unit = "photons/pulse" if data.quantity == "photons_per_pulse" else data.quantity

        self.spot_slider = Slider(start=0, end=max(data.n_files - 1, 1), value=0, step=1,
                                  title="laser spot (file)", name="spot_slider", disabled=data.n_files < 2,
                                  width=300)
        self.time_slider = Slider(start=0, end=max(T - 1, 1), value=0, step=1, title="time bin",
                                  name="time_slider", width=500, css_classes=["time-slider"])
        self.play = Button(label="► play", width=80, name="play_button")
        self.scale = RadioButtonGroup(labels=["colour scale: per frame", "per spot"], active=0, name="scale")
        self.hist_scale = RadioButtonGroup(labels=["linear", "log"], active=0, name="hist_scale")

        self.f_int, self.s_int, self.m_int = image_figure(
            "time-integrated (click a pixel)", "pixel x", "pixel y", (0, W, 0, H), tools="tap,pan,wheel_zoom,reset",
            colorbar_title=unit, name="integrated_image")
        self.f_slice, self.s_slice, self.m_slice = image_figure(
            "time slice", "pixel x", "pixel y", (0, W, 0, H), tools="tap,pan,wheel_zoom,reset",
            colorbar_title=unit, name="slice_image")
        self.marker = ColumnDataSource(data={"x": [self.px + 0.5], "y": [self.py + 0.5]})
        for f in (self.f_int, self.f_slice):
            f.scatter("x", "y", source=self.marker, marker="square", size=10, fill_alpha=0, line_color="cyan",
                      line_width=2)
            f.on_event(Tap, self._on_tap)
        self.f_xt, self.s_xt, self.m_xt = image_figure(
            "x-t streak (row of the clicked pixel)", "time (ps)", "pixel x", (t0, t1, 0, W), width=500,
            colorbar_title=unit, name="xt_image")
        self.f_yt, self.s_yt, self.m_yt = image_figure(
            "y-t streak (column of the clicked pixel)", "time (ps)", "pixel y", (t0, t1, 0, H), width=500,
            colorbar_title=unit, name="yt_image")
        self.t_spans = [Span(location=t0, dimension="height", line_color="cyan", line_dash="dashed")
                        for _ in range(2)]
        self.f_xt.add_layout(self.t_spans[0])
        self.f_yt.add_layout(self.t_spans[1])

        self.hist_src = ColumnDataSource(data={"t": [], "v": [], "vlog": []})
        self.f_hist = figure(title="histogram of the clicked pixel", width=500, height=260,
                             x_axis_label="time (ps)", y_axis_label=unit, tools="pan,wheel_zoom,box_zoom,reset",
                             name="pixel_hist", css_classes=["tmv-pixel_hist"])
        self.f_hist.line("t", "v", source=self.hist_src, color="#c0392b")
        self.f_hist_log = figure(title="histogram of the clicked pixel (log)", width=500, height=260,
                                 x_axis_label="time (ps)", y_axis_label=unit, y_axis_type="log",
                                 tools="pan,wheel_zoom,box_zoom,reset", visible=False)
        self.f_hist_log.line("t", "vlog", source=self.hist_src, color="#c0392b")
        self.h_span = Span(location=t0, dimension="height", line_color="#2c3e50", line_dash="dashed")
        self.f_hist.add_layout(self.h_span)
        self.f_hist_log.add_layout(self.h_span)

        self.wall = self._wall_figure()
        self.facts = Div(text=facts_html(data.facts(), "manifest"), width=380, name="manifest_facts")

        self.spot_slider.on_change("value", lambda a, o, n: self._set_spot(n))
        self.time_slider.on_change("value", lambda a, o, n: self._set_time(n))
        self.scale.on_change("active", lambda a, o, n: self._update_slice())
        self.hist_scale.on_change("active", lambda a, o, n: self._toggle_log(n))
        self.play.on_click(self._toggle_play)

        self.layout = column(
            row(self.spot_slider, self.time_slider, self.play, self.scale),
            row(self.f_int, self.f_slice, self.wall, self.facts),
            row(self.f_xt, self.f_yt),
            row(self.f_hist, self.f_hist_log, self.hist_scale),
            self.status.div,
        )
        self._set_spot(0)
        peak = int(np.argmax(data.spot(0).sum(axis=(0, 1))))
        self.time_slider.value = peak  # open on the brightest time bin

    # ------------------------------------------------------------ the wall

    def _wall_figure(self):
        from bokeh.models import ColumnDataSource
        from bokeh.plotting import figure

        f = figure(title="relay wall: pixel patches, laser spots", width=300, height=300, match_aspect=True,
                   x_axis_label="wall x (m)", y_axis_label="wall y (m)", tools="pan,wheel_zoom,reset",
                   name="wall_figure", css_classes=["tmv-wall_figure"])
        if not self.data.has_wall:
            f.title.text = "no relay wall (camera capture)"
            f.text(x=[0], y=[0], text=["no wall geometry"], text_align="center")
            self.wall_active = self.wall_pixel = None
            return f
        px, sp, active, fp = self.data.wall_points(0)
        f.rect(x=px[..., 0].ravel(), y=px[..., 1].ravel(), width=fp, height=fp, fill_color="#95a5a6",
               fill_alpha=0.35, line_color="#7f8c8d", legend_label="pixel patches")
        f.scatter(x=sp[:, 0], y=sp[:, 1], size=6, color="#2980b9", legend_label="laser spots")
        self.wall_active = ColumnDataSource(data={"x": active[:, 0], "y": active[:, 1]})
        f.scatter("x", "y", source=self.wall_active, size=11, color="#e74c3c", legend_label="this spot")
        self.wall_pixel = ColumnDataSource(data={"x": [px[self.py, self.px, 0]], "y": [px[self.py, self.px, 1]]})
        f.rect("x", "y", width=fp, height=fp, source=self.wall_pixel, fill_alpha=0, line_color="cyan", line_width=2)
        f.legend.label_text_font_size = "9px"
        f.legend.location = "top_left"
        f.legend.background_fill_alpha = 0.5
        self._wall_px = px
        return f

    # ----------------------------------------------------------- callbacks

    def _on_tap(self, event) -> None:
        x, y = int(np.floor(event.x)), int(np.floor(event.y))
        if 0 <= x < self.data.width and 0 <= y < self.data.height:
            self.px, self.py = x, y
            self._update_pixel()
            self.status.done(f"pixel ({y}, {x})")

    def _set_spot(self, j: int) -> None:
        self.spot_j = int(j)
        hist = self.data.spot(self.spot_j)
        self._spot_max = robust_max(hist)
        set_image(self.s_int, self.m_int, hist.sum(axis=-1), low=0.0)
        if self.data.has_wall:
            _, _, active, _ = self.data.wall_points(self.spot_j)
            self.wall_active.data = {"x": active[:, 0], "y": active[:, 1]}
        self._update_slice()
        self._update_pixel()
        self.status.done(f"spot {self.spot_j}")

    def _set_time(self, b: int) -> None:
        self.t_bin = int(b)
        self._update_slice()
        self.status.done(f"bin {self.t_bin}")

    def _update_slice(self) -> None:
        d = self.data
        hist = d.spot(self.spot_j)
        t = d.times_ps[self.t_bin]
        per_spot = self.scale.active == 1
        set_image(self.s_slice, self.m_slice, hist[:, :, self.t_bin], low=0.0,
                  high=self._spot_max if per_spot else None)
        self.f_slice.title.text = f"time slice: bin {self.t_bin}, t = {t:.1f} ps"
        for s in self.t_spans:
            s.location = float(t)
        self.h_span.location = float(t)

    def _update_pixel(self) -> None:
        d = self.data
        hist = d.spot(self.spot_j)
        t0, t1 = d.t0_ps, d.t0_ps + d.n_bins * d.bin_width_ps
        set_image(self.s_xt, self.m_xt, hist[self.py, :, :], extent=(t0, t1, 0, d.width), low=0.0)
        set_image(self.s_yt, self.m_yt, hist[:, self.px, :], extent=(t0, t1, 0, d.height), low=0.0)
        v = hist[self.py, self.px].astype(np.float64)
        pos = v[v > 0]
        floor = float(pos.min()) * 0.5 if pos.size else 1e-30
        self.hist_src.data = {"t": d.times_ps, "v": v, "vlog": np.maximum(v, floor)}
        self.f_hist.title.text = self.f_hist_log.title.text = \
            f"histogram of pixel (y={self.py}, x={self.px}), spot {self.spot_j}: sum {v.sum():.4g}"
        self.f_xt.title.text = f"x-t streak (row y = {self.py})"
        self.f_yt.title.text = f"y-t streak (column x = {self.px})"
        self.marker.data = {"x": [self.px + 0.5], "y": [self.py + 0.5]}
        if self.wall_pixel is not None:
            p = self._wall_px[self.py, self.px]
            self.wall_pixel.data = {"x": [p[0]], "y": [p[1]]}

    def _toggle_log(self, active: int) -> None:
        self.f_hist.visible = active == 0
        self.f_hist_log.visible = active == 1

    def _toggle_play(self) -> None:
        if self._play_cb is None:
            self._play_cb = self.doc.add_periodic_callback(self._step, PLAY_PERIOD_MS)
            self.play.label = "❚❚ pause"
        else:
            self.stop()

    def _step(self) -> None:
        self.time_slider.value = (self.time_slider.value + 1) % self.data.n_bins

    def stop(self) -> None:
        """Stop playing (when the page closes or another capture is chosen)."""
        if self._play_cb is not None:
            try:
                self.doc.remove_periodic_callback(self._play_cb)
            except ValueError:
                pass
            self._play_cb = None
            self.play.label = "► play"
