"""NaN / -inf path lengths and negative dropped fractions are bugs: counted apart, reported, never hidden."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import transient_mi  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]


def test_lane_histogram_counts_invalid_path_lengths_apart():
    import drjit as dr
    import mitsuba as mi

    from transient_mi.integrators._lanes import LaneHistogram, LaneLayout
    from transient_mi.time_axis import TimeAxis

    axis = TimeAxis(0.0, 10.0, 8)
    h = LaneHistogram(LaneLayout(n_pixels=6, spp=1, streams=1), axis, pad=0)
    c_m_per_ps = 299792458.0 * 1e-12
    lanes = mi.UInt32([0, 1, 2, 3, 4, 5])  # one record per lane and call, as the integrators do
    opl = mi.Float([float("nan"), -float("inf"), float("inf"), 35.0 * c_m_per_ps, 1e9, 15.0 * c_m_per_ps])
    value = mi.Float([1.0, 1.0, 1.0, 2.0, 1.0, float("nan")])
    h.record(lanes, opl, value, mi.Bool(True))
    h.evaluate()
    # NaN and -inf path lengths, and the NaN value: invalid; +inf (no time of flight) and 1e9 m: out of range
    assert h.invalid_count() == 3
    assert int(h._counters()[:, 0].sum()) == 2
    hist, steady, dropped, frac = h.collect(np.array([1.0]))
    assert dropped == 2
    np.testing.assert_array_equal(hist[3], np.eye(8, dtype=np.float32)[3] * 2.0)  # 35 ps -> bin 3
    assert hist[[0, 1, 2, 4, 5]].sum() == 0
    assert np.isfinite(steady).all() and steady[[0, 1, 5]].sum() == 0.0  # invalid light is in no total
    assert steady[2] == 1.0 and steady[4] == 1.0  # out-of-range light is in the steady total
    assert h.negative_fraction == 0.0
    dr.eval()


def test_negative_dropped_fraction_is_recorded():
    from transient_mi.integrators._lanes import NEGATIVE_FRACTION_TOL, dropped_fraction

    class H:
        negative_fraction = 0.0

    h = H()
    assert dropped_fraction(h, 1.0, 1.0 + 0.5 * NEGATIVE_FRACTION_TOL) == 0.0 and h.negative_fraction == 0.0
    assert dropped_fraction(h, 1.0, 1.01) == 0.0
    assert abs(h.negative_fraction + 0.01) < 1e-12
    assert dropped_fraction(h, 2.0, 1.0) == 0.5


def test_render_reports_invalid_contributions_in_the_manifest(tmp_path):
    """A result with invalid contributions (injected) lands in the manifest's 'dropped' and in a warning."""
    from transient_core import stack
    from transient_mi.render_capture import prepare_render, run_render

    job = prepare_render(ROOT / "scenes" / "nlos_point_targets.xml", tmp_path / "c",
                         defines={"width": "2", "height": "2", "spots_x": "1", "spots_y": "1", "n_bins": "16",
                                  "bin_width_ps": "200"}, spp=8, seed=0)
    real = job.integrator.render_transient

    def injected(*a, **kw):
        res = real(*a, **kw)
        for r in res if isinstance(res, list) else [res]:
            r.invalid_contributions = 3
            r.negative_fraction = -0.002
        return res

    job.integrator.render_transient = injected
    lines = []
    run_render(job, progress=False, log=lines.append)
    d = stack.read_manifest(tmp_path / "c")["dropped"]
    assert d["invalid_path_lengths"] == 3 and d["negative_fraction"] == -0.002
    assert any(line.startswith("warning: 3 contribution(s) had a NaN or -inf path length") and "bug" in line
               for line in lines)


def test_clean_render_reports_zero_invalid(tmp_path):
    from transient_core import stack
    from transient_mi.render_capture import render

    render(ROOT / "scenes" / "nlos_point_targets.xml", tmp_path / "c",
           defines={"width": "2", "height": "2", "spots_x": "1", "spots_y": "1", "n_bins": "16",
                    "bin_width_ps": "200"}, spp=8, seed=0, progress=False)
    d = stack.read_manifest(tmp_path / "c")["dropped"]
    assert d["invalid_path_lengths"] == 0 and d["negative_fraction"] == 0.0
