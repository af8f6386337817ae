"""Reconstruction panel: method, voxel size, filter and threshold chosen live; maximum-intensity
projections along each axis, the depth map, a rotatable 3-D point cloud of the kept voxels, the
ground-truth mesh overlaid when known, and the metrics table (all computed with :mod:`recon`).

The 3-D view is an orthographic projection computed on the server (azimuth about the wall's y axis,
then elevation), drawn back to front; the kept voxels (``volume > 0`` after the threshold, at most
:data:`MAX_POINTS` of the strongest) are coloured by depth z, the ground-truth surface is drawn as grey
points sampled uniformly by area (seeded).
"""

from __future__ import annotations

import math
import time

import numpy as np

from .plotting import Status, facts_html, image_figure, set_image

__all__ = ["ReconPanel", "VOXEL_CHOICES", "project_points"]

VOXEL_CHOICES = (16, 32, 48, 64, 96)
DEFAULT_VOXELS = 32
THRESHOLDS = ("rel:0.3", "rel:0.1", "rel:0.5", "rel:0.7", "otsu", "none")
MAX_POINTS = 20000
GT_SAMPLES = 4000


def project_points(p: np.ndarray, center: np.ndarray, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Orthographic view coordinates ``(u, v, depth)`` of points ``p[n, 3]`` (metres).

    The camera turns ``azimuth_deg`` about the y axis, then ``elevation_deg`` about the new x axis;
    at (0, 0) it looks along +z from the wall, so ``u = x``, ``v = y``, ``depth = z``.
    """
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    ry = np.array([[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]])
    rx = np.array([[1, 0, 0], [0, math.cos(e), -math.sin(e)], [0, math.sin(e), math.cos(e)]])
    return (np.asarray(p, dtype=np.float64) - center) @ (rx @ ry).T


class ReconPanel:
    """Bokeh layout and callbacks for reconstructing one capture (or re-filtering a stored volume).

    Parameters
    ----------
    capture : recon.Capture or None
        The capture to reconstruct; None when only a stored reconstruction is shown.
    stored : recon.Reconstruction or None
        A reconstruction read from ``volume.npz``; shown first, re-filtered when filter/threshold change.
    ground_truth : path or None
        A mesh to overlay and score against.
    """

    def __init__(self, capture, doc, stored=None, ground_truth=None, bounds=None):
        from bokeh.layouts import column, row
        from bokeh.models import ColumnDataSource, Div, LinearColorMapper, Select, Slider
        from bokeh.plotting import figure

        from recon.pipeline import CONFOCAL_ONLY, METHODS

        self.capture, self.doc, self.stored, self.bounds = capture, doc, stored, bounds
        self.rec = stored
        self._raw = None  # ((method, voxels), reconstruction) of the last run, re-filtered without rerunning
        self.status = Status("recon")
        self.metrics_status = Status("metrics")
        self.computed = False
        self.gt = self.gt_points = None
        self.gt_error = None
        if ground_truth is not None:
            try:
                from recon.metrics import load_ground_truth

                self.gt = load_ground_truth(ground_truth)
                self.gt_points = self._sample_gt(self.gt)
            except Exception as e:  # a broken mesh must not take the viewer down
                self.gt_error = f"ground truth {ground_truth}: {e}"
        methods = [m for m in METHODS if capture is not None and (capture.mode == "confocal" or m not in CONFOCAL_ONLY)]
        first = methods[0] if methods else "stored"
        if stored is not None:
            first = stored.method if stored.method in methods else first
            if not methods:
                methods = [stored.method]
                first = stored.method
        self.method = Select(title="method", value=first, options=methods, disabled=capture is None,
                             name="method_select",
                             css_classes=["method-select"], width=140)
        self.voxels = Select(title="voxels per axis (voxel size)",
                             value="stored" if stored is not None else str(DEFAULT_VOXELS),
                             options=self._voxel_options(), disabled=capture is None, name="voxels_select", width=240,
                             css_classes=["voxels-select"])
        self.filter = Select(title="filter", value="paper", options=["paper", "none"], name="filter_select",
                             width=110)
        self.threshold = Select(title="threshold", value="rel:0.3", options=list(THRESHOLDS),
                                name="threshold_select", width=110)
        for w in (self.method, self.voxels, self.filter, self.threshold):
            w.on_change("value", lambda a, o, n: self.update())
        self.azimuth = Slider(start=-180, end=180, value=35, step=5, title="3-D view azimuth (deg)", width=220,
                              name="azimuth_slider")
        self.elevation = Slider(start=-90, end=90, value=20, step=5, title="elevation (deg)", width=220,
                                name="elevation_slider")
        for w in (self.azimuth, self.elevation):
            w.on_change("value", lambda a, o, n: self._update_3d())

        self.figs = {}
        for key, title, xl, yl in (("z", "MIP along z (front)", "x (m)", "y (m)"),
                                   ("y", "MIP along y (top)", "x (m)", "z (m)"),
                                   ("x", "MIP along x (side)", "z (m)", "y (m)")):
            self.figs[key] = image_figure(title, xl, yl, (0, 1, 0, 1), width=330, height=300, palette="Viridis256",
                                          name=f"mip_{key}")
        self.fig_depth = image_figure("depth map: z of each column's maximum", "x (m)", "y (m)", (0, 1, 0, 1),
                                      width=330, height=300, palette="Turbo256", colorbar_title="z (m)",
                                      name="depth_map")
        self.gt_src = {k: ColumnDataSource(data={"a": [], "b": []}) for k in ("z", "y", "x")}
        for k, (f, _, _) in self.figs.items():
            f.scatter("a", "b", source=self.gt_src[k], size=1.5, color="white", alpha=0.25)
            if self.gt_points is not None:
                f.title.text += " + ground truth (white)"
        self.cloud_src = ColumnDataSource(data={"u": [], "v": [], "z": [], "alpha": []})
        self.gt3_src = ColumnDataSource(data={"u": [], "v": []})
        self.cloud_mapper = LinearColorMapper(palette="Turbo256", low=0, high=1)
        self.f3d = figure(title="3-D view: kept voxels (colour = depth z)", width=420, height=380,
                          match_aspect=True, tools="pan,wheel_zoom,reset", name="view3d", css_classes=["tmv-view3d"],
                          x_axis_label="screen u (m)", y_axis_label="screen v (m)")
        self.f3d.scatter("u", "v", source=self.gt3_src, size=2, color="#7f8c8d", alpha=0.4)
        if self.gt_points is not None:
            self.f3d.title.text += "; grey: ground truth"
        self.f3d.scatter("u", "v", source=self.cloud_src, size=4, alpha="alpha",
                         color={"field": "z", "transform": self.cloud_mapper})
        self.metrics = Div(text="", width=360, name="metrics_table")

        controls = row(self.method, self.voxels, self.filter, self.threshold)
        self.layout = column(
            controls,
            row(self.figs["z"][0], self.figs["y"][0], self.figs["x"][0]),
            row(self.fig_depth[0], self.f3d, column(self.azimuth, self.elevation, self.metrics,
                                                     self.metrics_status.div)),
            self.status.div,
        )

    # ------------------------------------------------------------- helpers

    def _voxel_options(self) -> list[tuple[str, str]]:
        out = []
        if self.stored is not None:
            s = self.stored.grid.shape
            out.append(("stored", f"stored grid {s[2]}x{s[1]}x{s[0]}"))
        if self.capture is None:
            return out or [(str(DEFAULT_VOXELS), str(DEFAULT_VOXELS))]
        for n in VOXEL_CHOICES:
            try:
                b = self.bounds or _default_bounds(self.capture)
                size = "x".join(f"{1e3 * (b[2 * i + 1] - b[2 * i]) / n:.3g}" for i in range(3))
                out.append((str(n), f"{n}^3 ({size} mm)"))
            except Exception:
                out.append((str(n), f"{n}^3"))
        return out

    @staticmethod
    def _sample_gt(gt) -> np.ndarray | None:
        if gt.points is not None:
            return gt.points
        if gt.mesh is None:
            return None
        import trimesh

        pts, _ = trimesh.sample.sample_surface(gt.mesh, GT_SAMPLES, seed=0)
        return np.asarray(pts)

    # --------------------------------------------------------------- update

    def update(self) -> None:
        """Reconstruct (or re-filter the stored volume) and redraw; metrics follow on the next tick."""
        from transient_core.errors import UserInputError
        from recon.filters import no_filter, paper_filter
        from recon.pipeline import reconstruct

        t_start, cpu_start = time.perf_counter(), time.process_time()
        try:
            if self.stored is not None and not self.computed:
                self.rec = self.stored  # as written by transient-mi recon, filter included
            elif self.capture is not None:
                key = (self.method.value, self.voxels.value)
                if self._raw is not None and self._raw[0] == key:
                    # only the filter or threshold changed: filter the same raw volume again
                    f = paper_filter if self.filter.value == "paper" else no_filter
                    self.rec = f(self._raw[1], threshold=self.threshold.value)
                else:
                    if self.voxels.value == "stored":
                        kw = {"grid": self.stored.grid}
                    else:
                        kw = {"voxels": int(self.voxels.value)}
                        if self.bounds is not None:
                            kw["bounds"] = self.bounds
                    self.rec = reconstruct(self.capture, self.method.value, filter=self.filter.value,
                                           threshold=self.threshold.value, **kw)
                    self._raw = (key, self.rec)
            elif self.stored is not None:
                f = paper_filter if self.filter.value == "paper" else no_filter
                self.rec = f(self.stored, threshold=self.threshold.value)
            else:
                self.status.error("nothing to reconstruct")
                return
        except UserInputError as e:
            self.status.error(str(e))
            return
        self.computed = True
        self._draw()
        ms = 1e3 * (time.perf_counter() - t_start)
        cpu_ms = 1e3 * (time.process_time() - cpu_start)  # all threads of the server process
        nz, ny, nx = self.rec.grid.shape
        kept = int(np.count_nonzero(self.rec.volume > 0))
        if self.rec is self.stored:
            what = f"stored {self.rec.method} reconstruction ({self.rec.filter.get('name', '?')} filter)"
        else:
            what = f"{self.rec.method}, filter {self.filter.value}, threshold {self.threshold.value}"
        self.status.done(f"{self.rec.method} on {nx}x{ny}x{nz} voxels: {what}: {kept:,} voxels kept, "
                         f"{ms:.0f} ms ({cpu_ms:.0f} ms CPU)")
        self.metrics.text = "<i>computing metrics...</i>" if self.gt is not None else (
            self.gt_error or "no ground-truth mesh known for this capture (give --ground-truth FILE)")
        if self.gt is not None:
            self.doc.add_next_tick_callback(self._metrics)

    def _draw(self) -> None:
        from recon.filters import depth_map, projections

        rec = self.rec
        x, y, z = rec.x_m, rec.y_m, rec.z_m
        b = rec.grid.bounds
        proj = projections(rec.volume)
        ext = {"z": (b[0], b[1], b[2], b[3]), "y": (b[0], b[1], b[4], b[5]), "x": (b[4], b[5], b[2], b[3])}
        imgs = {"z": proj["z"], "y": proj["y"], "x": proj["x"].T}  # x: [z, y] -> rows y, columns z
        for k, (f, src, mapper) in self.figs.items():
            set_image(src, mapper, imgs[k], extent=ext[k], low=0.0 if imgs[k].min() >= 0 else None)
            f.x_range.update(start=ext[k][0], end=ext[k][1])
            f.y_range.update(start=ext[k][2], end=ext[k][3])
        f, src, mapper = self.fig_depth
        set_image(src, mapper, depth_map(rec.volume, rec.grid), extent=ext["z"], low=b[4], high=b[5])
        f.x_range.update(start=b[0], end=b[1])
        f.y_range.update(start=b[2], end=b[3])
        if self.gt_points is not None:
            g = self.gt_points
            self.gt_src["z"].data = {"a": g[:, 0], "b": g[:, 1]}
            self.gt_src["y"].data = {"a": g[:, 0], "b": g[:, 2]}
            self.gt_src["x"].data = {"a": g[:, 2], "b": g[:, 1]}
        vol = rec.volume
        idx = np.flatnonzero(vol > 0)
        if idx.size > MAX_POINTS:
            idx = idx[np.argpartition(vol.ravel()[idx], -MAX_POINTS)[-MAX_POINTS:]]
        iz, iy, ix = np.unravel_index(idx, vol.shape)
        self._cloud = np.stack([x[ix], y[iy], z[iz]], axis=-1)
        v = vol.ravel()[idx].astype(np.float64)
        self._cloud_alpha = 0.25 + 0.75 * (v / v.max()) if v.size and v.max() > 0 else np.ones_like(v)
        self._center = np.array([(b[0] + b[1]) / 2, (b[2] + b[3]) / 2, (b[4] + b[5]) / 2])
        self.cloud_mapper.update(low=b[4], high=b[5])
        self._update_3d()

    def _update_3d(self) -> None:
        if self.rec is None:
            return
        az, el = float(self.azimuth.value), float(self.elevation.value)
        q = project_points(self._cloud, self._center, az, el)
        order = np.argsort(-q[:, 2])  # far first, near last
        self.cloud_src.data = {"u": q[order, 0], "v": q[order, 1], "z": self._cloud[order, 2],
                               "alpha": self._cloud_alpha[order]}
        if self.gt_points is not None:
            g = project_points(self.gt_points, self._center, az, el)
            self.gt3_src.data = {"u": g[:, 0], "v": g[:, 1]}

    def _metrics(self) -> None:
        from recon.metrics import compute_metrics

        t_start = time.perf_counter()
        try:
            m = compute_metrics(self.rec, self.gt, seed=0)
        except Exception as e:  # metrics are extra information: report, keep the view
            self.metrics.text = f"metrics failed: {e}"
            self.metrics_status.error(str(e))
            return
        rows = []
        for k, v in m.items():
            if isinstance(v, float):
                rows.append((k, f"{1e3 * v:.2f} mm" if k.endswith("_m") else f"{v:.4g}"))
            elif isinstance(v, (int, str)) and not isinstance(v, bool):
                rows.append((k, str(v)))
        self.metrics.text = facts_html(rows, "metrics against the ground truth")
        self.metrics_status.done(f"{len(rows)} metrics, {1e3 * (time.perf_counter() - t_start):.0f} ms")


def _default_bounds(capture):
    from recon.grid import default_bounds

    return default_bounds(capture)


def unavailable_layout(message: str):
    """The reconstruction tab for data it cannot reconstruct (camera captures)."""
    from bokeh.models import Div

    return Div(text=f"<p style='font-size:14px'>{message}</p>", name="recon_unavailable", width=700)
