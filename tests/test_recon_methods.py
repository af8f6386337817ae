"""Reconstruction methods on closed-form synthetic captures.

- backprojection equals a brute-force reference (float tolerance);
- phasor fields (FFT/RSD) equal the direct sum of their defining formula;
- every method puts the maximum within one voxel of a point reflector,
  for single-spot, multi-spot and confocal captures, with and without the
  first/last segments;
- two points 5 cm apart are resolved by BP + the paper's filter and by
  phasor fields;
- bad input gives clear errors.
"""

import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from recon.backprojection import backprojection, box_sum, filtered_backprojection, voxel_path_bins
from recon.capture import Capture
from transient_core.errors import UserInputError
from recon.grid import VoxelGrid, make_grid
from recon.phasor import _phasors, phasor_fields, virtual_wave
from recon.pipeline import reconstruct
from recon.synthetic import point_capture, wall_grid

C = 299792458.0 * 1e-12  # m per ps


# ------------------------------------------------------------------ references


def brute_force_bp(capture, grid, hists=None):
    """sum over (spot j, pixel k) of the bin containing |v-S_j| + |v-P_k| + offsets, per voxel (numpy, float64)."""
    V = grid.centers().reshape(-1, 3)
    out = np.zeros(len(V), dtype=np.complex128 if hists is not None and np.iscomplexobj(hists) else np.float64)
    P = capture.pixel_centers.reshape(-1, 3)
    w = capture.bin_width_ps * C
    t0 = capture.t0_ps * C
    for j in range(capture.n_files):
        h = (capture.spot(j) if hists is None else hists[j]).reshape(len(P), -1)
        off = capture.path_offsets_m(j).reshape(-1)
        for k in range(len(P)):
            S = capture.spots[k] if capture.mode == "confocal" else capture.spots[j]
            L = np.linalg.norm(V - S, axis=1) + np.linalg.norm(V - P[k], axis=1) + off[k]
            b = np.floor((L - t0) / w).astype(np.int64)
            ok = (b >= 0) & (b < h.shape[1])
            out[ok] += h[k, b[ok]]
    return out.reshape(grid.shape)


def _irregular_capture():
    """Array capture with 3 spots, pixels off a regular grid and off the plane, first/last included."""
    rng = np.random.default_rng(7)
    P = wall_grid(4, 3, 0.6)
    P = P + rng.normal(0, 0.01, P.shape)
    n = np.tile([0.0, 0.0, 1.0], (3, 4, 1))
    spots = np.array([[0.0, 0.0, 0.0], [0.2, -0.1, 0.01], [-0.15, 0.12, -0.02]])
    T = 400
    data = rng.random((3, 3, 4, T)).astype(np.float32)
    return Capture.from_arrays(data, spots=spots, pixel_centers=P, pixel_normals=n, laser_origin=[-0.5, 0, 1.0],
                               detector_origin=[-0.5, 0.2, 1.0], t0_ps=9000.3, bin_width_ps=9.7,
                               include_first_last=True)


TINY = VoxelGrid.from_bounds((-0.31, 0.29, -0.27, 0.33, 0.2, 0.71), voxels=(7, 6, 5))


@pytest.mark.parametrize("which", ["irregular_array", "confocal_first_last", "single_spot"])
def test_bp_equals_brute_force(which):
    if which == "irregular_array":
        cap = _irregular_capture()
    elif which == "confocal_first_last":
        cap = point_capture([[0.05, 0.02, 0.45]], mode="confocal", pixels=(3, 4), sigma_ps=40, include_first_last=True)
    else:
        cap = point_capture([[0.05, 0.02, 0.45]], pixels=(5, 4), sigma_ps=40, t0_ps=3123.4)
    ref = brute_force_bp(cap, TINY)
    got = backprojection(cap, TINY, voxel_integration=False).raw
    assert ref.max() > 0
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-6 * ref.max())
    # with voxel integration: the same sum over histograms box-summed over the voxel's path range
    n = voxel_path_bins(cap, TINY)
    assert n > 1
    boxed = [box_sum(cap.spot(j), n) for j in range(cap.n_files)]
    naive = [np.stack([np.convolve(h, np.ones(n), mode="full")[(n - 1) - (n - 1) // 2:][: cap.n_bins]
                       for h in cap.spot(j).reshape(-1, cap.n_bins)]).reshape(cap.spot(j).shape)
             for j in range(cap.n_files)]
    np.testing.assert_allclose(boxed, naive, rtol=1e-5, atol=1e-5 * np.max(naive))
    ref_i = brute_force_bp(cap, TINY, hists=np.array(boxed, dtype=np.float64))
    got_i = backprojection(cap, TINY).raw
    np.testing.assert_allclose(got_i, ref_i, rtol=1e-5, atol=1e-6 * ref_i.max())


def test_fbp_is_backprojection_of_time_filtered_histograms():
    cap = _irregular_capture()
    sigma_m = 3 * cap.bin_width_m
    filt = [-gaussian_filter1d(cap.spot(j).astype(np.float64), sigma_m / cap.bin_width_m, axis=-1, order=2,
                               mode="constant") for j in range(cap.n_files)]
    ref = brute_force_bp(cap, TINY, hists=np.array(filt))
    got = filtered_backprojection(cap, TINY, sigma_m=sigma_m).raw
    np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-5 * np.abs(ref).max())


@pytest.mark.parametrize("mode", ["array", "confocal"])
def test_phasor_rsd_equals_direct_sum(mode):
    cap = point_capture([[0.05, -0.03, 0.4]], mode=mode, pixels=(6, 5), sigma_ps=15, bin_width_ps=8,
                        include_first_last=True)
    # voxels divide the pixel pitch (0.2 m along x, 1/6 m along y): RSD evaluates exactly at voxel centres
    grid = VoxelGrid.from_bounds((-0.5, 0.5, -0.5, 0.5, 0.3, 0.5), voxels=(10, 12, 4))
    ref, f_max = _direct_phasor(cap, grid, mode)
    rec = phasor_fields(cap, grid, method="rsd")
    assert rec.params["implementation"] == "rsd"
    np.testing.assert_allclose(rec.raw, ref, rtol=1e-4, atol=1e-5 * ref.max())
    # voxels that do not divide the pitch: computed on a finer aligned grid, then bilinear interpolation.
    # |error| <= sum over the 2 axes of h^2/8 |U''| with |U''| <= (2 pi k)^2 |U|, k <= 2 f_max (two legs).
    grid = VoxelGrid.from_bounds((-0.31, 0.3, -0.3, 0.29, 0.3, 0.5), voxels=(9, 7, 3))
    ref, f_max = _direct_phasor(cap, grid, mode)
    rec = phasor_fields(cap, grid, method="rsd")
    h = max(0.2 / math.ceil(0.2 / grid.voxel_size_m[0]), (1 / 6) / math.ceil((1 / 6) / grid.voxel_size_m[1]))
    bound = 2 * h ** 2 / 8 * (2 * math.pi * 2 * f_max) ** 2
    assert np.max(np.abs(rec.raw - ref)) <= bound * ref.max()


def _direct_phasor(cap, grid, mode):
    freqs, w, _, _ = virtual_wave(cap, None, None, grid)
    P = _phasors(cap, 0, cap.spot(0), freqs).reshape(len(freqs), -1)             # first/last removed as phases
    V = grid.centers().reshape(-1, 3)
    Pc = cap.pixel_centers.reshape(-1, 3)
    S = Pc if mode == "confocal" else cap.spots[[0]]
    dP = np.linalg.norm(V[:, None] - Pc[None], axis=-1)
    dS = np.linalg.norm(V[:, None] - S[None], axis=-1)
    L = dP + dS
    U = np.einsum("f,fk,vkf->v", w, P, np.exp(2j * np.pi * L[..., None] * freqs))
    return np.abs(U).reshape(grid.shape), float(freqs.max())


def test_phasors_equal_their_defining_sum():
    """``_phasors`` (the numba kernel, complex128 sums rounded once) against the formula in float64: each value
    within the complex64 rounding of its magnitude, 2^-24 |P|, plus the float64 sum's own error."""
    cap = point_capture([[0.05, -0.03, 0.4], [-0.1, 0.1, 0.5]], pixels=(6, 5), sigma_ps=15, bin_width_ps=8,
                        include_first_last=True)
    freqs, _, _, _ = virtual_wave(cap, None, None, None)
    h = cap.spot(0)
    got = _phasors(cap, 0, h, freqs).reshape(len(freqs), -1)
    T = h.shape[-1]
    r = cap.t0_m + (np.arange(T) + 0.5) * cap.bin_width_m
    off = cap.path_offsets_m(0).reshape(-1)
    hh = np.asarray(h, dtype=np.float32).astype(np.float64).reshape(-1, T)
    ref = (hh @ np.exp(-2j * np.pi * np.outer(r, freqs))).T * np.exp(2j * np.pi * np.outer(freqs, off))
    total = np.abs(hh).sum(axis=1)[None, :]
    assert np.all(np.abs(got - ref) <= 2.0 ** -24 * np.abs(ref) * 2 + 1e-12 * total)


def test_phasor_bytes_do_not_depend_on_the_thread_count(tmp_path):
    """Phasor fields (both implementations) give the same bytes with 1 and 2 threads of numba and BLAS: no
    reduction whose order follows the thread count (a BLAS product's did)."""
    import hashlib
    import os
    import subprocess
    import sys

    script = tmp_path / "run.py"
    script.write_text(
        "import hashlib, numpy as np\n"
        "from recon.grid import VoxelGrid\n"
        "from recon.phasor import phasor_fields\n"
        "from recon.synthetic import point_capture\n"
        "cap = point_capture([[0.05, -0.03, 0.4], [-0.1, 0.1, 0.5]], pixels=12, sigma_ps=15, bin_width_ps=8,\n"
        "                    spots=[[-0.2, 0, 0], [0.2, 0, 0]], include_first_last=True)\n"
        "grid = VoxelGrid.from_bounds((-0.31, 0.3, -0.3, 0.29, 0.3, 0.5), voxels=(9, 7, 3))\n"
        "for m in ('rsd', 'backprojection'):\n"
        "    print(m, hashlib.sha256(phasor_fields(cap, grid, method=m).raw.tobytes()).hexdigest())\n")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    outs = []
    for n in ("1", "2"):
        env = {**os.environ, "NUMBA_NUM_THREADS": n, "OPENBLAS_NUM_THREADS": n, "OMP_NUM_THREADS": n,
               "MKL_NUM_THREADS": n, "PYTHONPATH": root}
        r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, cwd=root)
        assert r.returncode == 0, r.stderr
        outs.append(r.stdout)
    assert outs[0] == outs[1] and outs[0].count("\n") == 2
    assert hashlib.sha256(b"").hexdigest() not in outs[0]


def test_phasor_rsd_agrees_with_backprojection_form():
    """Same formula, two discretisations: the BP form samples the filtered signal at fine-bin centres
    (bins/4), so each term's phase errs by at most 2 pi f_max w/8."""
    cap = point_capture([[0.08, -0.05, 0.45]], pixels=16, sigma_ps=20, bin_width_ps=8)
    grid = VoxelGrid.from_bounds((-0.5, 0.5, -0.5, 0.5, 0.35, 0.55), voxels=(16, 16, 6))
    a = phasor_fields(cap, grid, method="rsd").raw
    b = phasor_fields(cap, grid, method="backprojection").raw
    freqs, *_ = virtual_wave(cap, None, None, grid)
    bound = 2 * math.pi * freqs.max() * cap.bin_width_m / 8
    assert np.max(np.abs(a - b)) <= bound * a.max()


# ------------------------------------------------------------------ localisation of a point

TRUE = np.array([0.07, -0.04, 0.45])
GRID = VoxelGrid.from_bounds((-0.3, 0.3, -0.3, 0.3, 0.2, 0.7), voxel_size_m=0.025)


def _geometry(name, first_last):
    common = dict(pixels=32, wall_size_m=0.8, bin_width_ps=8, sigma_ps=20, include_first_last=first_last)
    if name == "single_spot":
        return point_capture([TRUE], spots=[[-0.1, 0.05, 0.0]], **common)
    if name == "multi_spot":
        return point_capture([TRUE], spots=wall_grid(3, 3, 0.5).reshape(-1, 3), spot_grid=(3, 3), **common)
    return point_capture([TRUE], mode="confocal", **common)


CASES = [(g, m, fl) for g in ("single_spot", "multi_spot", "confocal")
         for m in (("bp", "fbp", "phasor", "lct", "fk") if g == "confocal" else ("bp", "fbp", "phasor"))
         for fl in (False, True)]


@pytest.mark.parametrize("geometry,method,first_last", CASES)
def test_maximum_within_one_voxel_of_the_point(geometry, method, first_last):
    cap = _geometry(geometry, first_last)
    rec = reconstruct(cap, method, GRID, filter="paper")
    vs = np.array(GRID.voxel_size_m)
    for which in ("raw", "volume"):
        err = np.abs(rec.argmax_m(which) - TRUE)
        assert np.all(err <= vs + 1e-12), (which, rec.argmax_m(which), TRUE)


# ------------------------------------------------------------------ two points 5 cm apart

PAIR = np.array([[-0.025, 0.005, 0.405], [0.025, 0.005, 0.405]])   # on voxel centres of PAIR_GRID
PAIR_GRID = VoxelGrid.from_bounds((-0.1, 0.1, -0.1, 0.1, 0.3, 0.5), voxel_size_m=0.01)
RAYLEIGH_DIP = 8 / math.pi ** 2   # intensity at the midpoint of two sinc^2 peaks at the Rayleigh limit


def _resolved(rec):
    """Two maxima along the line through the points, each within one voxel of a point, with a dip between
    them at least as deep as Rayleigh's criterion."""
    g = rec.grid
    vol = rec.volume
    iz = int(np.argmin(np.abs(g.z_m - PAIR[0, 2])))
    iy = int(np.argmin(np.abs(g.y_m - PAIR[0, 1])))
    line = vol[iz, iy]                     # profile along the line through the two points
    x = g.x_m
    left = np.argmax(np.where(x < 0, line, -np.inf))
    right = np.argmax(np.where(x > 0, line, -np.inf))
    assert abs(x[left] - PAIR[0, 0]) <= g.voxel_size_m[0] + 1e-12, line
    assert abs(x[right] - PAIR[1, 0]) <= g.voxel_size_m[0] + 1e-12, line
    dip = line[left: right + 1].min() / min(line[left], line[right])
    assert dip <= RAYLEIGH_DIP, (dip, line)
    # and the volume's maximum is one of the two points
    peak = rec.argmax_m()
    assert min(np.max(np.abs(peak - p) / g.voxel_size_m) for p in PAIR) <= 1 + 1e-9, peak


def test_two_points_5cm_apart_resolved_by_bp_and_paper_filter():
    cap = point_capture(PAIR, mode="confocal", pixels=16, bin_width_ps=4, sigma_ps=10)
    _resolved(reconstruct(cap, "bp", PAIR_GRID, filter="paper", threshold="none"))


@pytest.mark.parametrize("geometry", ["confocal", "multi_spot", "single_spot"])
def test_two_points_5cm_apart_resolved_by_phasor_fields(geometry):
    if geometry == "confocal":
        cap = point_capture(PAIR, mode="confocal", pixels=16, bin_width_ps=4, sigma_ps=10)
    elif geometry == "multi_spot":
        cap = point_capture(PAIR, pixels=32, spots=wall_grid(3, 3, 0.6).reshape(-1, 3), spot_grid=(3, 3),
                            bin_width_ps=4, sigma_ps=10)
    else:
        cap = point_capture(PAIR, pixels=64, bin_width_ps=4, sigma_ps=10)
    _resolved(reconstruct(cap, "phasor", PAIR_GRID, filter="none", wavelength_m=0.04))


# ------------------------------------------------------------------ errors


def test_confocal_only_methods_on_array_capture():
    cap = point_capture([TRUE], pixels=8, sigma_ps=20)
    for m in ("lct", "fk"):
        with pytest.raises(UserInputError, match=f"--method {m} needs a confocal capture.*use bp, fbp or phasor"):
            reconstruct(cap, m, voxels=8)


def test_lct_needs_square_regular_grid():
    cap = point_capture([TRUE], mode="confocal", pixels=(8, 8), wall_size_m=(0.8, 0.6), sigma_ps=20)
    with pytest.raises(UserInputError, match=r"equal pixel spacing along x and y; .* dx=0\.1 m, dy=0\.075 m"):
        reconstruct(cap, "fk", voxels=8)


def test_bounds_must_be_in_the_hidden_space():
    cap = point_capture([TRUE], pixels=8, sigma_ps=20)
    with pytest.raises(UserInputError, match=r"lies behind the relay wall: the hidden space is z > 0"):
        make_grid(cap, bounds=(-0.5, 0.5, -0.5, 0.5, -1.0, -0.1))
    with pytest.raises(UserInputError, match=r"zmin=-0.2 m is behind the relay wall"):
        make_grid(cap, bounds=(-0.5, 0.5, -0.5, 0.5, -0.2, 0.5))
    with pytest.raises(UserInputError, match=r"zmin=5 m is deeper than the time axis can see"):
        make_grid(cap, bounds=(-0.5, 0.5, -0.5, 0.5, 5, 6))
    with pytest.raises(UserInputError, match=r"xmin=1 must be smaller than xmax=0"):
        make_grid(cap, bounds=(1, 0, -0.5, 0.5, 0.1, 0.5))


def test_empty_threshold_is_an_error():
    cap = point_capture([TRUE], pixels=8, sigma_ps=20)
    with pytest.raises(UserInputError, match=r"threshold 'abs:1e30' .* keeps no voxel: the filtered volume's maximum"):
        reconstruct(cap, "bp", voxels=8, threshold="abs:1e30")
    with pytest.raises(UserInputError, match=r"threshold 'rel:2': relative fraction must lie in \(0, 1\]"):
        reconstruct(cap, "bp", voxels=8, threshold="rel:2")
    # a capture without signal: nothing survives any threshold
    empty = Capture.from_arrays(np.zeros_like(cap.data), spots=cap.spots, pixel_centers=cap.pixel_centers,
                                laser_origin=cap.laser_origin, detector_origin=cap.detector_origin,
                                t0_ps=cap.t0_ps, bin_width_ps=cap.bin_width_ps)
    for spec in ("otsu", "rel:0.3"):
        with pytest.raises(UserInputError, match="keeps no voxel: the filtered volume's maximum is 0"):
            reconstruct(empty, "bp", voxels=8, threshold=spec)


def test_phasor_wavelength_below_nyquist_is_an_error():
    cap = point_capture([TRUE], pixels=8, sigma_ps=20, bin_width_ps=10)
    with pytest.raises(UserInputError, match="too short for bins of .* use a wavelength of at least"):
        reconstruct(cap, "phasor", voxels=8, wavelength_m=0.005)


def test_float32_positions_of_rendered_captures_are_a_regular_grid():
    """Rendered captures store positions in float32 (~1e-7 m off the grid): LCT, f-k and the RSD path accept
    them, and the result equals that of the exact grid."""
    cap = _geometry("confocal", False)
    rng = np.random.default_rng(3)
    P = (cap.pixel_centers + rng.normal(0, 1e-7, cap.pixel_centers.shape) * [1, 1, 0]).astype(np.float32)
    S = (cap.spots + rng.normal(0, 1e-7, cap.spots.shape) * [1, 1, 0]).astype(np.float32)
    jit = Capture.from_arrays(cap.data, mode="confocal", spots=S, pixel_centers=P, laser_origin=cap.laser_origin,
                              detector_origin=cap.detector_origin, t0_ps=cap.t0_ps, bin_width_ps=cap.bin_width_ps)
    for method in ("lct", "fk", "phasor", "bp"):
        a = reconstruct(cap, method, GRID, filter="none")
        b = reconstruct(jit, method, GRID, filter="none")
        assert b.params.get("implementation", "rsd") == "rsd"
        np.testing.assert_allclose(b.raw, a.raw, rtol=1e-3, atol=1e-3 * np.abs(a.raw).max())
