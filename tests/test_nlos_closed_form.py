"""NLOS capture against closed forms: three-bounce light of a small Lambertian patch, the wall return,
an empty hidden space.

Reference values come from ``nlos_helpers`` (numpy quadrature of the
radiometric chain, written independently of the renderer).
"""

import math

import numpy as np
import pytest

import transient_mi  # noqa: F401  (LLVM + variant + plug-ins)
from nlos_helpers import (LASER, DETECTOR, bin_of, nlos_scene, patch_centers, render, seed_stats, square,
                          three_bounce_reference, wall_return_reference)
from transient_core.units import C_M_PER_PS
from stats_helpers import chi2_bounds, t_bound, t_to_z

X0 = np.array([0.05, -0.03, 0.35])
SIDE = 0.02
TARGET_ALBEDO = 0.6
W = H = 4
FP = 0.01
BW = 8.0
N_SEEDS = 16
SPP = 128
#: False-failure rate of test_three_bounce_small_patch per parametrisation, for its whole family of statistical
#: checks: 16 pixel means, the sum over pixels and the joint chi-square (Bonferroni over 18).
ALPHA_FAMILY = 0.003
N_CHECKS = W * H + 2


def _scene(include_first_last, t0_ps):
    return nlos_scene(width=W, height=H, footprint=FP, include_first_last=include_first_last,
                      include_wall_return=False, max_depth=4, n_bins=400, bin_width_ps=BW, t0_ps=t0_ps,
                      hidden=[square(X0, SIDE, TARGET_ALBEDO)])


@pytest.mark.parametrize("include_first_last,t0_ps", [(True, 11000.0), (False, 1500.0)])
def test_three_bounce_small_patch(include_first_last, t0_ps):
    scene = _scene(include_first_last, t0_ps)
    S = np.zeros(3)  # single laser spot at the wall centre
    centers = patch_centers(W, H, FP)
    runs = np.stack([render(scene, seed=s, spp=SPP) for s in range(N_SEEDS)])  # [seed, H, W, T]
    totals = runs.sum(-1)
    mean, se = seed_stats(totals)
    hist = runs.mean(0)
    L_S = np.linalg.norm(LASER - S)
    refs = np.zeros((H, W))
    for y in range(H):
        for x in range(W):
            ref, opl_lo, opl_hi = three_bounce_reference(S, centers[y, x], FP, X0, SIDE, TARGET_ALBEDO)
            refs[y, x] = ref
            # total photons per pixel = the analytic product of the geometry terms; with the standard error
            # estimated from the same 16 seeds, (mean - ref) / se is Student-t with 15 degrees of freedom
            assert se[y, x] > 0
            t = (mean[y, x] - ref) / se[y, x]
            bound = t_bound(N_SEEDS, ALPHA_FAMILY, N_CHECKS)
            assert abs(t) < bound, f"pixel ({x},{y}): {mean[y, x]:.6g} vs analytic {ref:.6g} (t = {t:+.2f})"
            # arrival times: every recorded photon (hence the peak bin) lies in the range that the
            # patch's and the target's extents allow
            if include_first_last:
                # |p - D| over the patch
                g = np.linspace(-0.5, 0.5, 9) * FP
                P = np.stack(np.meshgrid(centers[y, x, 0] + g, centers[y, x, 1] + g), -1).reshape(-1, 2)
                dpd = np.linalg.norm(np.c_[P, np.zeros(len(P))] - DETECTOR, axis=1)
                lo = opl_lo + L_S + dpd.min()
                hi = opl_hi + L_S + dpd.max()
            else:
                lo, hi = opl_lo, opl_hi
            b_lo, b_hi = bin_of(lo, t0_ps, BW), bin_of(hi, t0_ps, BW)
            h = hist[y, x]
            peak = int(np.argmax(h))
            assert b_lo <= peak <= b_hi, f"pixel ({x},{y}): peak bin {peak} outside [{b_lo}, {b_hi}]"
            nz = np.nonzero(h)[0]
            assert nz.min() >= b_lo and nz.max() <= b_hi
            # centre of the allowed range, for a readable check of the time origin
            centre_ps = (0.5 * (lo + hi)) / C_M_PER_PS
            assert abs(t0_ps + (peak + 0.5) * BW - centre_ps) <= 0.5 * (hi - lo) / C_M_PER_PS + BW
    # the sum over all pixels (Student t, 15 degrees of freedom), and the pixels jointly: each pixel's t mapped to
    # an exactly normal z, whose squares sum to a chi-square with 16 degrees of freedom (pixels are independent:
    # each has its own paths); all three kinds of check share the family-wise rate ALPHA_FAMILY
    total_se = totals.sum(axis=(1, 2)).std(ddof=1) / np.sqrt(N_SEEDS)
    assert abs(mean.sum() - refs.sum()) < t_bound(N_SEEDS, ALPHA_FAMILY, N_CHECKS) * total_se
    chi2 = float((t_to_z((mean - refs) / se, N_SEEDS - 1) ** 2).sum())
    lo, hi = chi2_bounds(H * W, ALPHA_FAMILY, N_CHECKS)
    assert lo < chi2 < hi, (chi2, lo, hi)


def test_first_last_shifts_by_the_segment_lengths():
    """Including first/last segments moves each pixel's light by |L - S| + |p - D| (over its patch)."""
    a = render(_scene(True, 11000.0), seed=3, spp=SPP)
    b = render(_scene(False, 1500.0), seed=3, spp=SPP)
    np.testing.assert_allclose(a.sum(-1), b.sum(-1), rtol=1e-5)  # same paths, same weights
    centers = patch_centers(W, H, FP)
    t = 11000.0 + (np.arange(400) + 0.5) * BW
    t2 = 1500.0 + (np.arange(400) + 0.5) * BW
    for y in range(H):
        for x in range(W):
            shift = (np.linalg.norm(LASER) + np.linalg.norm(centers[y, x] - DETECTOR)) / C_M_PER_PS
            mean_a = (a[y, x] * t).sum() / a[y, x].sum()
            mean_b = (b[y, x] * t2).sum() / b[y, x].sum()
            # |p - D| varies over the 1 cm patch by < footprint; plus one bin of rounding each
            assert abs(mean_a - mean_b - shift) < FP / C_M_PER_PS + 2 * BW


@pytest.mark.parametrize("include_first_last", [True, False])
def test_empty_hidden_space_gives_only_the_wall_return(include_first_last):
    t0 = 9000.0 if include_first_last else -50.0
    spots = (3, 2)
    Wd, Hd, fp = 7, 5, 0.045  # no spot lies on a patch boundary
    scene = nlos_scene(width=Wd, height=Hd, footprint=fp, spots=spots, spacing=0.1,
                       include_first_last=include_first_last, n_bins=300, bin_width_ps=10.0, t0_ps=t0, hidden=[],
                       max_depth=-1)
    centers = patch_centers(Wd, Hd, fp)
    grid = patch_centers(spots[0], spots[1], 0.1).reshape(-1, 3)
    for j, S in enumerate(grid):
        h = render(scene, seed=j, spp=16, spot=j)
        photons, opl = wall_return_reference(S)
        if not include_first_last:
            opl = 0.0
        # the pixel whose patch contains the spot (planar wall: S is its own projection)
        ix = int(math.floor(S[0] / fp + Wd / 2))
        iy = int(math.floor(S[1] / fp + Hd / 2))
        assert np.all(np.abs(centers[iy, ix, :2] - S[:2]) < fp / 2)
        b = bin_of(opl, t0, 10.0)
        expected = np.zeros_like(h)
        expected[iy, ix, b] = photons
        nz = np.argwhere(h != 0)
        assert nz.tolist() == [[iy, ix, b]], f"spot {j}: non-zero entries at {nz.tolist()}"
        np.testing.assert_allclose(h, expected, rtol=2e-5, atol=0)


def test_empty_hidden_space_without_wall_return_is_zero():
    scene = nlos_scene(width=4, height=4, footprint=0.05, include_wall_return=False, hidden=[], max_depth=-1,
                       n_bins=100, bin_width_ps=20.0, t0_ps=9000.0)
    h = render(scene, seed=0, spp=32)
    assert not np.any(h)


def test_confocal_empty_scene_every_pixel_sees_its_own_spot():
    scene = nlos_scene(width=3, height=3, footprint=0.1, capture="confocal", hidden=[], n_bins=300,
                       bin_width_ps=10.0, t0_ps=9000.0)
    h = render(scene, seed=0, spp=8)
    centers = patch_centers(3, 3, 0.1)
    for y in range(3):
        for x in range(3):
            photons, opl = wall_return_reference(centers[y, x])
            b = bin_of(opl, 9000.0, 10.0)
            assert np.nonzero(h[y, x])[0].tolist() == [b]
            assert h[y, x, b] == pytest.approx(photons, rel=2e-5)


def test_pixel_pitch_spreads_small_patches_over_the_wall():
    """A 3 x 3 array of 1 cm patches at 15 cm pitch (the paper's sparse focused array): each pixel
    matches the closed form for its own patch, centred on the pitch grid (4 sigma per pixel = 3 sigma
    family-wise for 9 pixels)."""
    pitch, fp, n = 0.15, 0.01, 3
    x0 = np.array([0.02, 0.04, 0.30])
    scene = nlos_scene(width=n, height=n, footprint=fp, pitch=pitch, include_wall_return=False, max_depth=4,
                       n_bins=400, bin_width_ps=BW, t0_ps=1000.0, include_first_last=False,
                       hidden=[square(x0, SIDE, TARGET_ALBEDO)])
    runs = np.stack([render(scene, seed=s, spp=SPP) for s in range(N_SEEDS)])
    mean, se = seed_stats(runs.sum(-1))
    centers = patch_centers(n, n, pitch)
    for y in range(n):
        for x in range(n):
            ref, _, _ = three_bounce_reference(np.zeros(3), centers[y, x], fp, x0, SIDE, TARGET_ALBEDO)
            z = (mean[y, x] - ref) / se[y, x]
            assert abs(z) < 4.0, f"pixel ({x},{y}): {mean[y, x]:.6g} vs analytic {ref:.6g} ({z:+.2f} sigma)"


def test_pixel_pitch_smaller_than_footprint_is_refused():
    with pytest.raises(Exception, match="pixel_pitch_m=0.005 is smaller than pixel_footprint_m=0.01"):
        nlos_scene(width=2, height=2, footprint=0.01, pitch=0.005)
