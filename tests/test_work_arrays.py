"""The quadrature's work arrays kept between render calls (transient_mi.integrators._work_arrays) and the rounding
residue cleared with the float32 copies in one pass (transient_mi.integrators._nlos_rounding.finish_rows).

Deterministic: no statistical tolerance (bytes are compared)."""

from __future__ import annotations

import numpy as np

import transient_mi  # noqa: F401  (LLVM + variant + plug-ins)
from transient_mi.integrators._nlos_rounding import ROUNDING_RESIDUE, finish_rows
from transient_mi.integrators._work_arrays import reuse_work_arrays, work_zeros


def test_outside_a_block_every_request_is_a_new_array_of_zeros():
    a = work_zeros("x", (2, 3))
    a += 1.0
    b = work_zeros("x", (2, 3))
    assert not np.shares_memory(a, b) and not b.any() and b.shape == (2, 3) and b.dtype == np.float64


def test_inside_a_block_the_array_is_handed_out_again_zeroed_and_freed_at_its_end():
    with reuse_work_arrays():
        a = work_zeros("hist", (4, 5), np.float32)
        a += 7.0
        b = work_zeros("hist", (4, 5), np.float32)
        assert np.shares_memory(a, b) and not b.any() and b.dtype == np.float32
        small = work_zeros("hist", (2, 5), np.float32)  # (a smaller group: a view of the kept array's start)
        assert np.shares_memory(small, a) and small.shape == (2, 5) and small.flags.c_contiguous
        other = work_zeros("bound", (4, 5), np.float32)  # (another name: its own array)
        assert not np.shares_memory(other, a)
        wider = work_zeros("hist", (8, 5), np.float32)  # (larger: a new array replaces the kept one)
        assert not np.shares_memory(wider, a) and wider.shape == (8, 5)
        assert np.shares_memory(work_zeros("hist", (4, 5), np.float32), wider)
        assert not np.shares_memory(work_zeros("hist", (4, 5), np.float64), wider)  # (another type: new)
        with reuse_work_arrays():  # (nested: the outer block's arrays)
            assert np.shares_memory(work_zeros("bound", (4, 5), np.float32), other)
        assert np.shares_memory(work_zeros("bound", (4, 5), np.float32), other)
    assert not np.shares_memory(work_zeros("bound", (4, 5), np.float32), other)


def _cleared(x: np.ndarray, light: np.ndarray) -> np.ndarray:
    """The rule in numpy: bins of ``x`` in ``[-ROUNDING_RESIDUE max|light row|, 0)`` set to 0 (a NaN in the light's
    row makes the limit NaN: nothing cleared)."""
    lim = -ROUNDING_RESIDUE * np.abs(light).max(axis=-1, keepdims=True)
    return np.where((x < 0) & (x >= lim), 0.0, x)


def test_finish_rows_equals_clearing_then_copying_to_float32():
    """One pass per row gives the values of the rule written in numpy (the light against itself, its error
    against the cleared light) and of ``astype(np.float32)``, in place, rows with a NaN and larger negatives as
    before (cleared nothing / kept for the writer to refuse)."""
    rng = np.random.default_rng(3)
    h = rng.random((3, 4, 9))
    h[0, 1, 2] = -1e-14                       # residue: cleared
    h[1, 0, 3] = -5.0 * ROUNDING_RESIDUE      # below the share of its row's largest (< 1): kept
    h[2, 3, 4] = np.nan                       # a NaN row clears nothing
    h[2, 3, 5] = -1e-15
    e = rng.random((3, 4, 9)) * 1e-3
    e[0, 1, 5] = -1e-15
    e[1, 2, 7] = -2.0
    want_h = _cleared(h, h)
    want_e = _cleared(e, want_h)
    hh, ee = h.copy(), e.copy()
    h32, e32 = finish_rows(hh, ee)
    assert hh.tobytes() == want_h.tobytes() and ee.tobytes() == want_e.tobytes()
    assert h32.tobytes() == want_h.astype(np.float32).tobytes()
    assert e32.tobytes() == want_e.astype(np.float32).tobytes()
    assert hh[0, 1, 2] == 0.0 and hh[1, 0, 3] < 0 and hh[2, 3, 5] < 0 and ee[0, 1, 5] == 0.0 and ee[1, 2, 7] == -2.0


def test_spot_groups_rendered_with_kept_arrays_are_the_same_bytes():
    """Groups of a capture rendered one call each inside a block (the arrays kept, the last group smaller) give
    the bytes of calls that allocate afresh, and no result refers to a kept array (a group's results are
    unchanged once the next group has been rendered). The paper's mannequin, 2 x 2 pixels, 2 x 2 spots, one cell
    (the cells' level too), the wall return on."""
    from transient_mi.scene_io import load_scene

    scene = load_scene("scenes/paper_mannequin.xml", dict(array="2", spots="2", n_bins="1152", bin_width_ps="10"))
    integ, sensor = scene.integrator(), scene.sensors()[0]
    groups = [[0, 1], [2, 3], [1]]
    names = ("histogram", "error_bound", "total_error_bound", "steady")

    def render(g):
        return integ.render_transient(scene, sensor, seed=0, spp=1, spots=g)

    fresh = [[{n: getattr(r, n).tobytes() for n in names} for r in render(g)] for g in groups]
    kept, held = [], []
    with reuse_work_arrays():
        for g in groups:
            rs = render(g)
            held.append(rs)
            kept.append([{n: getattr(r, n).tobytes() for n in names} for r in rs])
    assert kept == fresh
    assert [[{n: getattr(r, n).tobytes() for n in names} for r in rs] for rs in held] == fresh
    assert all(r.histogram.max() > 0 for rs in held for r in rs)
