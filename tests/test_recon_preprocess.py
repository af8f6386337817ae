"""Preprocessing: first/last removal, time resampling, crop, downsampling, pile-up correction."""

import numpy as np
import pytest

from recon.capture import Capture
from transient_core.errors import UserInputError
from recon.preprocess import (blind_cycles_from_manifest, crop_time, downsample_time, pileup_correction,
                              remove_first_last, resample_time_axis)
from recon.synthetic import point_capture, to_counts, wall_grid

C = 299792458.0 * 1e-12


def _moments(cap, j):
    h = cap.spot(j).astype(np.float64)
    tot = h.sum(-1)
    mean = (h * cap.times_ps).sum(-1) / tot
    return tot, mean


@pytest.mark.parametrize("mode", ["array", "confocal"])
def test_remove_first_last_shifts_each_histogram_by_its_segments(mode):
    kw = dict(spots=wall_grid(2, 1, 0.3).reshape(-1, 3), spot_grid=(1, 2)) if mode == "array" else {}
    cap = point_capture([[0.05, 0.1, 0.4]], mode=mode, pixels=(4, 3), sigma_ps=30, include_first_last=True, **kw)
    out = remove_first_last(cap)
    assert out.include_first_last is False and out.bin_width_ps == cap.bin_width_ps
    assert out.processing and "remove first/last" in out.processing[-1]
    for j in range(cap.n_files):
        tot0, mean0 = _moments(cap, j)
        tot1, mean1 = _moments(out, j)
        # the split of each bin between two neighbours keeps the photons and moves the mean exactly
        np.testing.assert_allclose(tot1, tot0, rtol=1e-5)
        np.testing.assert_allclose(mean0 - mean1, cap.path_offsets_m(j) / C, rtol=0, atol=1e-3 * cap.bin_width_ps)
    # and the histograms now peak at the three-bounce path
    o = np.array([0.05, 0.1, 0.4])
    S = cap.spot_positions(0)
    L = np.linalg.norm(o - S, axis=-1) + np.linalg.norm(o - cap.pixel_centers, axis=-1)
    _, mean = _moments(out, 0)
    np.testing.assert_allclose(mean, L / C, atol=cap.bin_width_ps)
    assert remove_first_last(out) is out


def test_resample_time_axis_to_zero_keeps_content():
    cap = point_capture([[0.05, 0.1, 0.4]], pixels=3, sigma_ps=30, t0_ps=3001.7)
    out = resample_time_axis(cap, 0.0)
    assert out.t0_ps == 0.0 and out.n_bins >= cap.n_bins + int(3001.7 / cap.bin_width_ps)
    t0, m0 = _moments(cap, 0)
    t1, m1 = _moments(out, 0)
    np.testing.assert_allclose(t1, t0, rtol=1e-5)
    np.testing.assert_allclose(m1, m0, atol=1e-3 * cap.bin_width_ps)


def test_crop_and_downsample():
    cap = point_capture([[0.05, 0.1, 0.4]], pixels=3, sigma_ps=30)
    w, t0 = cap.bin_width_ps, cap.t0_ps
    c = crop_time(cap, t0 + 10.5 * w, t0 + 40 * w)
    assert c.t0_ps == t0 + 10 * w and c.n_bins == 30
    np.testing.assert_array_equal(c.spot(0), cap.spot(0)[..., 10:40])
    d = downsample_time(cap, 4)
    assert d.bin_width_ps == 4 * w and d.n_bins == cap.n_bins // 4
    np.testing.assert_allclose(d.spot(0), cap.spot(0)[..., : d.n_bins * 4].reshape(3, 3, -1, 4).sum(-1), rtol=1e-6)
    counts = to_counts(cap, 10 ** 6, seed=0)
    dc = downsample_time(counts, 3)
    assert dc.spot(0).dtype == np.uint32
    np.testing.assert_array_equal(dc.spot(0), counts.spot(0)[..., : dc.n_bins * 3].reshape(3, 3, -1, 3).sum(-1))
    with pytest.raises(UserInputError, match="keeps no bin"):
        crop_time(cap, t0 - 100, t0 - 50)
    with pytest.raises(UserInputError, match="factor=0 must be a positive integer"):
        downsample_time(cap, 0)
    with pytest.raises(UserInputError, match="exceeds the"):
        downsample_time(cap, cap.n_bins + 1)


def test_pileup_correction_undoes_first_photon_pileup():
    """Expected counts of a first-photon TCSPC (N cycles, Poisson means lambda_b per cycle) are recovered."""
    N = 10 ** 9
    lam = np.array([0.0, 0.02, 0.3, 0.8, 0.5, 0.1, 0.0, 0.05])
    survive = np.exp(-np.concatenate([[0.0], np.cumsum(lam)[:-1]]))
    expected = N * survive * (1 - np.exp(-lam))
    data = np.round(np.broadcast_to(expected, (1, 2, 2, lam.size))).astype(np.uint32)
    cap = Capture.from_arrays(data, spots=[[0, 0, 0]], pixel_centers=wall_grid(2), bin_width_ps=5, kind="counts",
                              laser_origin=[0, 0, 1], detector_origin=[0, 0, 1],
                              manifest_extra={"detector": {"pulses": N}})
    out = pileup_correction(cap)
    np.testing.assert_allclose(out.spot(0)[0, 0], N * lam, rtol=1e-6, atol=2.0)
    np.testing.assert_allclose(pileup_correction(cap, n_cycles=N).spot(0), out.spot(0))
    with pytest.raises(UserInputError, match="needs a counts capture"):
        pileup_correction(point_capture([[0, 0, 0.4]], pixels=2, sigma_ps=20))
    no_pulses = Capture.from_arrays(data, spots=[[0, 0, 0]], pixel_centers=wall_grid(2), bin_width_ps=5,
                                    kind="counts")
    with pytest.raises(UserInputError, match="needs the number of laser pulses"):
        pileup_correction(no_pulses)


def test_pileup_correction_with_dead_time_longer_than_the_period():
    """Whole blind cycles (50 MHz laser, 50 ns TCSPC dead time, a short window: m = 2): the detector fires in a
    ready cycle with p_det and is then blind for m cycles, so the expected counts per bin are
    N p_b / (1 + m p_det); Coates on the live cycles recovers N lambda."""
    N = 10 ** 9
    lam = np.array([0.0, 0.02, 0.3, 0.8, 0.5, 0.1, 0.0, 0.05])
    survive = np.exp(-np.concatenate([[0.0], np.cumsum(lam)[:-1]]))
    p = survive * (1 - np.exp(-lam))
    m = 2
    expected = N * p / (1 + m * p.sum())
    data = np.round(np.broadcast_to(expected, (1, 2, 2, lam.size))).astype(np.uint32)
    det = {"pulses": N, "resolved": {"period_ps": 20000.0, "spad_dead_time_ps": 20000.0,
                                     "tcspc_dead_time_ps": 50000.0}}
    cap = Capture.from_arrays(data, spots=[[0, 0, 0]], pixel_centers=wall_grid(2), t0_ps=3000.0, bin_width_ps=500,
                              kind="counts", laser_origin=[0, 0, 1], detector_origin=[0, 0, 1],
                              manifest_extra={"detector": det})
    assert blind_cycles_from_manifest(cap)[0] == m                       # floor((3000 + 50000 - 7000) / 20000)
    out = pileup_correction(cap)
    assert "2 blind cycles" in out.processing[-1]
    np.testing.assert_allclose(out.spot(0)[0, 0], N * lam, rtol=1e-5, atol=5.0)
    # ignoring the dead time (classic Coates) underestimates
    assert np.all(pileup_correction(cap, blind_cycles=0).spot(0)[0, 0, 2:6] < 0.9 * N * lam[2:6])
