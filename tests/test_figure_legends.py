"""No legend covers data: the demo's Fig. 4 panels and the array-size study's plot keep legends off the axes."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure


def _capture(monkeypatch):
    figs = []
    orig = Figure.savefig

    def keep(self, *a, **k):
        figs.append(self)
        return orig(self, *a, **k)

    monkeypatch.setattr(Figure, "savefig", keep)
    return figs


def _assert_legends_off_the_axes(fig):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    legends = list(fig.legends) + [a.get_legend() for a in fig.axes if a.get_legend() is not None]
    assert legends
    for leg in legends:
        lb = leg.get_window_extent(renderer)
        for ax in fig.axes:
            assert not lb.overlaps(ax.get_window_extent(renderer)), (leg, ax.get_title())
        assert fig.bbox.contains(lb.x0, lb.y0) and fig.bbox.contains(lb.x1, lb.y1)  # not cut off either


def test_demo_histogram_figure_legend_is_off_the_panels(tmp_path, monkeypatch):
    from transient_mi.demo import QUICK, _figure_histograms

    figs = _capture(monkeypatch)
    t = np.linspace(10, 25, 200)
    peak = np.exp(-0.5 * ((t - 18) / 0.8) ** 2)
    hists = {n: (t, peak * 1e-3, 1e4 * peak + 1, {"gate_open_ps": 14000.0, "gate_close_ps": 23000.0})
             for n in (4, 8, 16, 32)}
    _figure_histograms(tmp_path / "fig4.png", hists, QUICK)
    _assert_legends_off_the_axes(figs[0])


def test_array_size_figure_legends_are_off_the_axes(tmp_path, monkeypatch):
    from transient_mi.study.figures import array_size_figure

    figs = _capture(monkeypatch)
    sizes = [4, 8, 16, 32, 64]
    rows = [{"array": n, "chamfer_m": 0.03 / n ** 0.3, "accuracy_m": 0.01, "completeness_m": 0.04 / n ** 0.2,
             "depth_mae_m": 0.008, "iou": 0.1 + 0.02 * i} for i, n in enumerate(sizes)]
    timings = [{"render_s": 0.1 * n, "detect_s": 0.05 * n, "reconstruct_s": 0.02 * n, "metrics_s": 0.5,
                "total_s": 0.17 * n + 0.5} for n in sizes]
    array_size_figure(tmp_path / "a.png", rows, timings)
    _assert_legends_off_the_axes(figs[0])
