"""Geometry derivatives of the deterministic three-bounce estimator (``estimator="quadrature"``):
transient_mi/integrators/_nlos_quadrature_geom.py and _nlos_mass_adjoint.py, hooked into ``render_backward``
(docs/quadrature.md, "Derivatives").

Scenes: those of tests/test_nlos_quadrature_ad.py (a 0.2 m Lambertian square 0.4 m in front of a 1 m relay
wall, 2 x 2 pixels, 128 bins of 50 ps, a 100 ps temporal kernel, 4 cm elements, 2 x 2 cells), without the
occluder: the derivative is the interior one (visibility held fixed), which central differences of the
primal see only while no visibility sample changes its verdict, and with nothing in the way none does.

Tolerances (every test here is deterministic: no false-failure rate to state):

* the bin masses in float64 against central differences of the primal's ``_masses`` with step 1e-6 bins:
  rounding ~1e-16 / 1e-6 = 1e-10 and truncation ~h^2 (h where a bin edge crosses a knot, the second
  derivative jumps: ~1e-6); tolerance 1e-5 of ``1 + |derivative|`` (measured: below 4e-7);
* the capture (float32 histograms) against central differences with steps of 0.25 mm and 0.05 rad: the
  truncation, ~h^2 f''' / 6, is ~1e-6 of the derivative at these steps (16x smaller than at 1 mm, where it
  is ~1e-3 along z), float32 rounding (6e-8 of a bin) divided by the relative step a few 1e-6 more
  (measured before the cell tilt: at most 6e-5). The primal's cell tilt (a first-order amplitude slope across
  a wall cell, main's dda01d8) has its terms' knot, width and tilt derivatives (both widths finite) and its
  curvature part's geometric dependence (2026-12-08), not its weight part's: measured at most 2.0e-3 (array)
  and 2.4e-3 (confocal), for the rotation about x (4e-3 before); tolerance relative 1e-2 until the weight part
  is differentiated.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

import transient_mi  # noqa: F401,E402  (before mitsuba/drjit)
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

import nlos_helpers as nh  # noqa: E402
from ad_helpers import detach_all  # noqa: E402
from test_nlos_quadrature_ad import _scene  # noqa: E402
from transient_mi.props import PluginParameterError  # noqa: E402

STEP_M = 2.5e-4
STEP_DEG = 0.2
REL_TOL = 1e-2


def _assert_knot_and_width_derivatives(out, loss, p0, h, trial, first=0):
    """``out[q + 1]`` (``mass_adjoint``'s derivative along ``p[q]``: ``t_lo, a, b, w1, w2``) against central
    differences of ``loss`` with step ``h``, for ``q`` from ``first``; neighbourhoods that would leave the knots'
    order or the widths' sign, and widths the primal ignores (0), are skipped. Tolerance 1e-5 of ``1 + |fd|``."""
    for q in range(first, 5):
        dp = np.zeros(5)
        dp[q] = h
        pp, pm = p0 + dp, p0 - dp
        if pm[1] < 0 or pp[1] > pp[2] or pm[2] < pm[1] or min(pm[3:]) < 0 or (q >= 3 and p0[q] == 0):
            continue  # (a one-sided neighbourhood, or a width the primal ignores)
        fd = (loss(pp) - loss(pm)) / (2 * h)
        assert abs(out[q + 1] - fd) <= 1e-5 * (1 + abs(fd)), (trial, q, fd, out[q + 1])


@pytest.mark.parametrize("slope", [False, True])
def test_mass_derivatives_equal_central_differences(slope):
    """d(sum_j r_j m_j) / d(t_lo, a, b, w1, w2) against central differences of the primal's masses, for
    random pairs including coincident knots (a = 0, a = b, a ~ 1e-6 b) and widths the primal treats as
    infinitesimal (w1 = 0; both zero); with ``slope`` each pair has the element's amplitude slope ``beta`` too (no
    cell tilt), whose term's knot and width derivatives (``mu`` moving with the knots included) are taken."""
    from transient_mi.integrators._nlos_mass_adjoint import mass_adjoint
    from transient_mi.integrators._nlos_time_spread import _masses

    rng = np.random.default_rng(1)
    n_ext, h = 40, 1e-6
    for trial in range(600):
        kind = trial % 6
        a0, b0 = sorted(rng.uniform(0, 6, 2))
        a0 = {1: 0.0, 2: b0, 3: 1e-6 * b0}.get(kind, a0)
        u1, u2 = rng.uniform(0, 4, 2)
        if kind >= 4:
            u1 = 0.0
        if kind == 5:
            u2, b0 = 0.0, max(b0, 1.0)
        p0 = np.array([rng.uniform(5, 25), a0, b0, u1, u2])
        row = rng.normal(size=n_ext)
        mu = (a0 + b0) / 3
        beta = rng.uniform(-0.6, 0.6) / max(mu, b0 - mu, 1e-9) if slope else 0.0

        def loss(p):
            buf = np.zeros(n_ext)
            f, last, _ = _masses(buf, *p, 0.0, 0.0, n_ext, beta)
            return float(np.dot(row[f:last + 1], buf[f:last + 1]))

        out = mass_adjoint(row, *p0, 0.0, 0.0, n_ext, beta)
        assert out[0] == pytest.approx(loss(p0), abs=1e-12)
        _assert_knot_and_width_derivatives(out, loss, p0, h, trial)


def test_tilted_mass_sum_and_shift_derivative_equal_the_primal():
    """With the cell's amplitude tilts (both widths finite: the fused path of ``mass_adjoint``, and one width
    infinitesimal), ``sum_j r_j m_j`` equals the primal's and its ``t_lo`` derivative equals central differences of
    the primal, and so do its derivatives along the tilts themselves and, with both widths finite, along the knots
    and widths (where a width is infinitesimal the tilts' terms' knot and width derivatives are not taken, as
    documented)."""
    from transient_mi.integrators._nlos_mass_adjoint import mass_adjoint
    from transient_mi.integrators._nlos_time_spread import _masses

    rng = np.random.default_rng(2)
    n_ext, h = 60, 1e-6
    for trial in range(400):
        a0, b0 = sorted(rng.uniform(0, 6, 2))
        a0 = {1: 0.0, 2: b0}.get(trial % 4, a0)
        u1, u2 = rng.uniform(0.05, 5, 2)
        if trial % 5 == 4:
            u1 = 0.0
        t1, t2 = rng.uniform(-1.0, 1.0, 2)
        p0 = np.array([rng.uniform(5, 40), a0, b0, u1, u2])
        row = rng.normal(size=n_ext)

        def loss(p, t_1=t1, t_2=t2):
            buf = np.zeros(n_ext)
            f, last, _ = _masses(buf, *p, t_1, t_2, n_ext)
            return float(np.dot(row[f:last + 1], buf[f:last + 1]))

        out = mass_adjoint(row, *p0, t1, t2, n_ext)
        assert out[0] == pytest.approx(loss(p0), abs=1e-11)
        dp = np.array([h, 0, 0, 0, 0])
        fd = (loss(p0 + dp) - loss(p0 - dp)) / (2 * h)
        assert abs(out[1] - fd) <= 1e-5 * (1 + abs(fd)), (trial, fd, out[1])
        if u1 > 0.0:  # both widths finite: the tilts' terms' knot and width derivatives are taken too
            _assert_knot_and_width_derivatives(out, loss, p0, h, trial, first=1)
        # the tilts' own derivatives: the masses are linear in each, so the difference quotient is exact to rounding
        for k, (d1, d2) in ((7, (0.1, 0.0)), (8, (0.0, 0.1))):
            dq = (loss(p0, t1 + d1, t2 + d2) - loss(p0, t1 - d1, t2 - d2)) / 0.2
            assert out[k] == pytest.approx(dq, rel=1e-7, abs=1e-10), (trial, k, out[k], dq)


def _rigid(scene, params, key, x0, t):
    T = mi.Transform4f
    params[key] = T().translate([t[0], t[1], t[2]]) @ T().rotate([1, 0, 0], t[3]) @ T().rotate([0, 1, 0], t[4]) @ x0
    params.update()


def _loss(scene, w) -> float:
    return float(np.sum(np.asarray(mi.render(scene), dtype=np.float64) * w))


def _backward(scene, params, setter, n, w):
    th = [mi.Float(0.0) for _ in range(n)]
    for t in th:
        dr.enable_grad(t)
    setter(th)
    img = mi.render(scene, params)
    dr.backward(dr.sum(img * mi.TensorXf(w), axis=None))
    g = np.array([float(dr.grad(t)[0]) for t in th])
    for t in th:
        dr.disable_grad(t)
    return g


@pytest.mark.parametrize("capture", ["array", "confocal"])
def test_rigid_motion_gradient_equals_central_differences(capture):
    """``to_world`` of the hidden square: translations along x, y, z and rotations about x and y, reverse mode
    against central differences of the primal; twice the same bytes."""
    scene = _scene(capture, occluder=False)
    params = mi.traverse(scene)
    key = "target.to_world"
    x0 = mi.Transform4f(params[key])
    w = np.random.default_rng(5).random((2, 2, 128)).astype(np.float32)

    def setter(t):
        _rigid(scene, params, key, x0, t)

    g = _backward(scene, params, setter, 5, w)
    assert np.array_equal(g, _backward(scene, params, setter, 5, w))
    for q, h in enumerate([STEP_M] * 3 + [STEP_DEG] * 2):
        lo = [0.0] * 5
        hi = [0.0] * 5
        lo[q], hi[q] = -h, h
        setter(hi)
        up = _loss(scene, w)
        setter(lo)
        fd = (up - _loss(scene, w)) / (2 * h)
        assert fd != 0 and g[q] == pytest.approx(fd, rel=REL_TOL), (q, g[q], fd)
    params[key] = x0
    params.update()
    detach_all(params)


def _mesh_scene():
    """The square as a four-vertex mesh without vertex normals (``vertex_positions`` exposed), facing the wall."""
    v = np.array([[-0.05, -0.08, 0.40], [0.15, -0.08, 0.42], [0.15, 0.12, 0.38], [-0.05, 0.12, 0.41]])
    f = np.array([[0, 2, 1], [0, 3, 2]], dtype=np.uint32)
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.6}})
    mesh = mi.Mesh("target", 4, 2, has_vertex_normals=False, props=props)
    mp = mi.traverse(mesh)
    mp["vertex_positions"] = mi.Float(v.astype(np.float32).ravel())
    mp["faces"] = mi.UInt32(f.ravel())
    mp.update()
    orig = mi.load_dict

    def load(d, **kw):
        d["sensor"]["film"]["kernel_sigma_ps"] = 100.0
        return orig(d, **kw)

    mi.load_dict = load
    try:
        scene = nh.nlos_scene(hidden=[mesh], n_bins=128, width=2, height=2, bin_width_ps=50.0, t0_ps=9000.0,
                              max_depth=4)
    finally:
        mi.load_dict = orig
    scene.integrator().nlos_options.update(estimator="quadrature", element_size_m=0.04, patch_cells=2,
                                           refine_levels=1)
    return scene


def _vertex_gradient(scene, params, key: str, v0: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The reverse-mode gradient (float32 ``[3 V]``) of ``sum(w * capture)`` with respect to the mesh's
    ``vertex_positions`` ``key`` set to ``v0``; the parameters are detached again afterwards."""
    vf = mi.Float(v0.astype(np.float32))
    dr.enable_grad(vf)
    params[key] = vf
    params.update()
    img = mi.render(scene, params)
    dr.backward(dr.sum(img * mi.TensorXf(w), axis=None))
    grad = np.asarray(dr.grad(vf), dtype=np.float32)
    detach_all(params)
    return grad


def test_vertex_positions_gradient_equals_central_differences():
    """A deformation (every vertex along its own random direction: areas, normals and knots change) of a mesh's
    ``vertex_positions``: the reverse-mode gradient dotted with the direction against a central difference."""
    scene = _mesh_scene()
    params = mi.traverse(scene)
    key = [k for k in params.keys() if k.endswith("vertex_positions")][0]
    v0 = np.asarray(params[key], dtype=np.float64)
    w = np.random.default_rng(5).random((2, 2, 128)).astype(np.float32)
    dirs = np.random.default_rng(2).normal(size=(3, v0.size))
    grad = _vertex_gradient(scene, params, key, v0, w).astype(np.float64)
    for d in dirs:
        d = d / np.abs(d).max()
        ls = []
        for s in (1, -1):
            params[key] = mi.Float((v0 + s * STEP_M * d).astype(np.float32))
            params.update()
            ls.append(_loss(scene, w))
        # (the float32 vertex buffer rounds the step: use the step it actually holds)
        held = (np.asarray(mi.Float((v0 + STEP_M * d).astype(np.float32)), dtype=np.float64)
                - np.asarray(mi.Float((v0 - STEP_M * d).astype(np.float32)), dtype=np.float64))
        fd = (ls[0] - ls[1])
        assert fd != 0 and float(grad @ held) == pytest.approx(fd, rel=REL_TOL)
    params[key] = mi.Float(v0.astype(np.float32))
    params.update()


def test_vertex_gradient_has_the_same_bytes_on_one_thread_and_on_two():
    """The vertex gradient's tiles (blocks of cells x blocks of elements, ``geometry_adjoint``) add into their own
    accumulators, summed in block order: one numba thread and two give the same bytes."""
    import numba

    assert numba.config.NUMBA_NUM_THREADS >= 2, "the test needs two numba threads to compare against one"
    scene = _mesh_scene()
    params = mi.traverse(scene)
    key = [k for k in params.keys() if k.endswith("vertex_positions")][0]
    v0 = np.asarray(params[key], dtype=np.float64)
    w = np.random.default_rng(7).random((2, 2, 128)).astype(np.float32)
    before = numba.get_num_threads()
    grads = []
    try:
        for threads in (1, 2):
            numba.set_num_threads(threads)
            grads.append(_vertex_gradient(scene, params, key, v0, w).tobytes())
    finally:
        numba.set_num_threads(before)
        params[key] = mi.Float(v0.astype(np.float32))
        params.update()
    assert grads[0] == grads[1] and np.any(np.frombuffer(grads[0], np.float32) != 0)


def test_what_is_not_differentiated_is_refused_in_one_line():
    """The relay wall's geometry, geometry in forward mode and a hidden shape whose BSDF is not diffuse."""
    scene = _scene(occluder=False)
    sensor = scene.sensors()[0]
    w = mi.TensorXf(np.zeros((2, 2, 128), np.float32))
    integ = scene.integrator()
    cases = [("relay_wall.to_world", lambda p: integ.render_backward(scene, p, w, sensor, 0, 1),
              r"relay_wall.to_world is being differentiated; estimator=quadrature cannot: the relay wall's geometry"),
             ("target.to_world", lambda p: integ.render_forward(scene, p, sensor, 0, 1),
              r"target.to_world is being differentiated; estimator=quadrature's forward mode differentiates BSDF "
              r"values")]
    for key, call, msg in cases:
        params = mi.traverse(scene)
        dr.enable_grad(params[key])
        params.update()
        with pytest.raises(PluginParameterError, match=msg) as e:
            call(params)
        assert "\n" not in str(e.value)
        detach_all(params)
    hidden = nh.square((0.05, 0.02, 0.4), 0.2, 0.6)
    hidden["bsdf"] = {"type": "roughplastic"}
    glossy = nh.nlos_scene(hidden=[hidden], n_bins=64, width=2, height=2, bin_width_ps=50.0, t0_ps=9000.0)
    glossy.integrator().nlos_options.update(estimator="quadrature")
    params = mi.traverse(glossy)
    dr.enable_grad(params["target.to_world"])
    params.update()
    with pytest.raises(PluginParameterError, match=r"its BSDF is not diffuse") as e:
        glossy.integrator().render_backward(glossy, params, mi.TensorXf(np.zeros((2, 2, 64), np.float32)),
                                            glossy.sensors()[0], 0, 1)
    assert "\n" not in str(e.value)
    detach_all(params)


def _sum_cdf(z, u1, u2):
    """CDF of ``U_1 + U_2`` (centred uniforms of widths ``u1``, ``u2``) at ``z`` (numpy, the reference's)."""
    if u1 == 0.0 and u2 == 0.0:
        return (z >= 0.0).astype(float)
    if u1 == 0.0 or u2 == 0.0:
        u = u1 + u2
        return np.clip(z / u + 0.5, 0.0, 1.0)
    h1, h2 = u1 / 2, u2 / 2
    R = lambda y: 0.5 * np.maximum(y, 0.0) ** 2  # noqa: E731
    return (R(z + h1 + h2) - R(z - h1 + h2) - R(z + h1 - h2) + R(z - h1 - h2)) / (u1 * u2)


def _slope_case(rng, trial: int, span: float, widths: tuple[float, float]):
    """A random pair with an element slope: knots ``0 <= a <= b`` below ``span`` bins (every 4th ``a = 0``, every
    4th after that ``a = b``), widths in ``widths`` (every 4th ``w1`` infinitesimal, every 4th after that both; then
    ``b >= 0.5``), and ``beta`` within the weight's clamp: ``(a, b, u1, u2, beta)``."""
    a, b = sorted(rng.uniform(0, span, 2))
    a = {1: 0.0, 2: b}.get(trial % 4, a)
    u1, u2 = rng.uniform(*widths, 2)
    if trial % 4 == 1:
        u1 = 0.0
    if trial % 4 == 2:
        u1 = u2 = 0.0
        b = max(b, 0.5)
    mu = (a + b) / 3
    return a, b, u1, u2, rng.uniform(-0.9, 0.9) / max(mu, b - mu, 1e-9)


def test_element_slope_masses_equal_a_numerical_integral():
    """The masses with the element's amplitude slope (the weight ``1 + beta (A - mu)`` over the triangular part
    ``A``) equal ``int rho(A) (1 + beta (A - mu)) P(A + U_1 + U_2 in bin) dA`` integrated numerically (midpoint rule
    on 400,000 points: error below 1e-9), with both widths finite, one, and none, for coincident knots too; their
    total is the pair's (the slope moves light, it does not add any)."""
    from transient_mi.integrators._nlos_time_spread import _masses

    rng = np.random.default_rng(7)
    n_ext = 64
    for trial in range(40):
        a, b, u1, u2, beta = _slope_case(rng, trial, 8.0, (0.2, 4.0))
        mu = (a + b) / 3
        tlo = rng.uniform(20, 30)
        buf = np.zeros(n_ext)
        first, last, inside = _masses(buf, tlo, a, b, u1, u2, 0.0, 0.0, n_ext, beta)
        got = np.zeros(n_ext)
        got[first:last + 1] = buf[first:last + 1]
        n = 400_000

        def weighted(lo, hi):  # (points and weights of the midpoint rule on [lo, hi], density times weight)
            x = lo + (np.arange(n) + 0.5) / n * (hi - lo)
            rho = np.where(x <= a, 2 * x / (b * a) if a > 0 else 0.0, 2 * (b - x) / (b * (b - a)) if b > a else 0.0)
            return x, rho * (1 + beta * (x - mu)) * ((hi - lo) / n)

        edges = np.arange(n_ext + 1, dtype=float)
        if u1 == 0.0 and u2 == 0.0:  # (a step: integrate up to the edge, so the integrand stays continuous)
            cdf = np.array([weighted(0.0, min(max(e - tlo, 0.0), b))[1].sum() for e in edges])
        else:
            x, w = weighted(0.0, b)
            cdf = np.array([np.sum(w * _sum_cdf(e - tlo - x, u1, u2)) for e in edges])
        want = np.diff(cdf)
        assert np.abs(got - want).max() <= 1e-9, (trial, np.abs(got - want).max())
        assert inside == pytest.approx(1.0, abs=1e-12)


def test_element_slope_is_the_regression_of_a_linear_amplitude():
    """For an amplitude linear in the time over the element (``r_v = 1 + s (t_v - t_mean)``) the slope is ``s``;
    an amplitude that does not vary with time (constant, or varying only along the knots' level line) gives 0;
    slopes that would make the weight negative are clamped to the largest that keeps it >= 0 with the cell's."""
    from transient_mi.integrators._nlos_element_slope import slope_of

    t = np.array([3.0, 5.0, 4.0])
    a, b = 1.0, 2.0  # sorted: 3, 4, 5
    for s in (0.3, -0.2, 0.0):
        r = 1 + s * (t - t.mean())
        assert slope_of(*t, *r, a, b, 0.0, 0.0) == pytest.approx(s, abs=1e-15)
    assert slope_of(3.0, 3.0, 5.0, 1.1, 0.9, 1.0, 0.0, 2.0, 0.0, 0.0) == pytest.approx(0.0, abs=1e-15)
    mu = (a + b) / 3
    reach = max(mu, b - mu)
    r = 1 + 5.0 * (t - t.mean())
    assert slope_of(*t, *r, a, b, 0.0, 0.0) == pytest.approx(1.0 / reach)
    assert slope_of(*t, *r, a, b, 0.5, -0.5) == pytest.approx(0.5 / reach)
    assert slope_of(2.0, 2.0, 2.0, 1.1, 0.9, 1.0, 0.0, 0.0, 0.0, 0.0) == 0.0


def test_element_slope_mass_sum_and_shift_derivative_equal_the_primal():
    """With the element's amplitude slope ``beta`` (and the cell's tilts), ``mass_adjoint``'s ``sum_j r_j m_j``
    equals the primal's, its ``t_lo`` derivative equals central differences of the primal and its ``beta``
    derivative the primal's difference over ``beta`` (the masses are linear in it), with both widths finite, one or
    none infinitesimal (the knot and width derivatives with a slope:
    ``test_mass_derivatives_equal_central_differences``; the cell tilts' own are not taken)."""
    from transient_mi.integrators._nlos_mass_adjoint import mass_adjoint
    from transient_mi.integrators._nlos_time_spread import _masses

    rng = np.random.default_rng(3)
    n_ext, h = 60, 1e-6
    for trial in range(300):
        a0, b0, u1, u2, beta = _slope_case(rng, trial, 6.0, (0.05, 5.0))
        t1, t2 = (rng.uniform(-0.5, 0.5, 2) if u1 > 0 and u2 > 0 else (0.0, 0.0))
        beta *= 0.5  # (room left for the cell's tilts: the weight stays >= 0)
        p0 = np.array([rng.uniform(5, 40), a0, b0, u1, u2])
        row = rng.normal(size=n_ext)

        def loss(p):
            buf = np.zeros(n_ext)
            f, last, _ = _masses(buf, *p, t1, t2, n_ext, beta)
            return float(np.dot(row[f:last + 1], buf[f:last + 1]))

        out = mass_adjoint(row, *p0, t1, t2, n_ext, beta, True)
        assert out[0] == pytest.approx(loss(p0), abs=1e-11)
        dp = np.array([h, 0, 0, 0, 0])
        fd = (loss(p0 + dp) - loss(p0 - dp)) / (2 * h)
        assert abs(out[1] - fd) <= 1e-5 * (1 + abs(fd)), (trial, fd, out[1])
        # the beta derivative: the masses are linear in beta, so the difference quotient is exact up to rounding
        buf = np.zeros(n_ext)
        f0, l0, _ = _masses(buf, *p0, t1, t2, n_ext, 0.0)
        m0 = float(np.dot(row[f0:l0 + 1], buf[f0:l0 + 1]))
        slope = (out[0] - m0) / beta if beta != 0.0 else out[6]
        assert out[6] == pytest.approx(slope, rel=1e-7, abs=1e-10), (trial, out[6], slope)

