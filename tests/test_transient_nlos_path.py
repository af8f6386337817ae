"""The NLOS integrator plug-in ``transient_nlos_path``: its parameters, its sensor, and its identity with
``transient_path`` under a ``spad_array`` (which delegates to it).

No statistics here: the estimator itself is tested in test_nlos_estimator.py and test_nlos_closed_form.py;
these tests compare bytes and error messages (deterministic, no false failures).
"""

from __future__ import annotations

import transient_mi  # noqa: F401  (LLVM set-up and plug-ins before mitsuba)
import mitsuba as mi
import numpy as np
import pytest
from nlos_helpers import nlos_scene, square
from transient_mi.props import PluginParameterError
from transient_mi.scene_io import mitsuba_error_message

HIDDEN = [square((0.05, 0.0, 0.4), 0.2, 0.7)]
#: a time window that holds the wall return and the hidden square's three-bounce light (~ 3.5 - 4.4 m)
WINDOW = {"n_bins": 64, "bin_width_ps": 50.0, "t0_ps": 11500.0}


def _plugin(**params):
    """Construct the plug-in directly from properties (its own exception, not Mitsuba's wrapper)."""
    from transient_mi.integrators.transient_nlos_path import TransientNLOSPath

    props = mi.Properties("transient_nlos_path")
    for k, v in params.items():
        props[k] = v
    return TransientNLOSPath(props)


@pytest.mark.parametrize("name, value, text", [
    ("max_depth", 0, "transient_nlos_path: max_depth=0 records nothing; use -1 (unlimited) or >= 1"),
    ("max_depth", -2, "transient_nlos_path: max_depth=-2 must be an integer >= -1"),
    ("max_depth", 2.5, "transient_nlos_path: max_depth=2.5 must be an integer"),
    ("rr_depth", 0, "transient_nlos_path: rr_depth=0 must be an integer >= 1"),
    ("variance_replicates", 0, "transient_nlos_path: variance_replicates=0 must be an integer >= 1"),
    ("variance_replicates", 2000, "transient_nlos_path: variance_replicates=2000 must be an integer <= 1024"),
    ("hidden_geometry_prob", 1.5, "transient_nlos_path: hidden_geometry_prob=1.5 must be"),
    ("hidden_geometry_prob", -0.1, "transient_nlos_path: hidden_geometry_prob=-0.1 must be"),
    ("rqmc", "yes", "transient_nlos_path: rqmc="),
    ("estimator", "simpson", "transient_nlos_path: estimator='simpson'; allowed: monte_carlo, quadrature"),
    ("element_size_m", 0.0, "transient_nlos_path: element_size_m=0 must be"),
    ("patch_cells", 0, "transient_nlos_path: patch_cells=0 must be"),
    ("refine_levels", 9, "transient_nlos_path: refine_levels=9 must be"),
])
def test_bad_parameters_fail_with_one_line_naming_parameter_and_value(name, value, text):
    with pytest.raises(PluginParameterError) as info:
        _plugin(**{name: value})
    msg = str(info.value)
    assert msg.startswith(text), msg
    assert "\n" not in msg
    # through Mitsuba's loader the render pipeline gets the same line back
    with pytest.raises(RuntimeError) as info:
        mi.load_dict({"type": "scene", "integrator": {"type": "transient_nlos_path", name: value}})
    assert mitsuba_error_message(info.value).startswith(text)


def test_defaults_and_good_values():
    i = _plugin()
    assert (i.max_depth_param, i.rr_depth, i.variance_replicates, i.replicates_for(True)) == (-1, 5, None, 1)
    quad = {"estimator": "monte_carlo", "element_size_m": 0.01, "patch_cells": 4, "refine_levels": 1,
            "element_slope": True}
    assert i.nlos_options == {"rqmc": True, "hidden_geometry_prob": 0.8, **quad}
    i = _plugin(max_depth=4, rr_depth=3, variance_replicates=8, rqmc=False, hidden_geometry_prob=0.0)
    assert (i.max_depth_param, i.rr_depth, i.replicates_for(True)) == (4, 3, 8)
    assert i.nlos_options == {"rqmc": False, "hidden_geometry_prob": 0.0, **quad}
    assert str(i).startswith("TransientNLOSPath[max_depth=4, rr_depth=3, variance_replicates=8")
    q = _plugin(estimator="quadrature", element_size_m=0.02, patch_cells=2, refine_levels=0)
    assert q.nlos_options == {"rqmc": True, "hidden_geometry_prob": 0.8, "estimator": "quadrature",
                              "element_size_m": 0.02, "patch_cells": 2, "refine_levels": 0, "element_slope": True}
    assert "estimator=quadrature, element_size_m=0.02, patch_cells=2, refine_levels=0" in q.to_string()
    assert "element_slope" not in q.to_string()  # (the default: its configurations keep their digests)
    flat = _plugin(estimator="quadrature", element_slope=False)
    assert flat.nlos_options["element_slope"] is False and "element_slope=false" in flat.to_string()
    assert "estimator" not in _plugin().to_string()  # Monte Carlo configurations keep their digests


def test_docstring_has_the_parameter_table():
    from transient_mi.integrators.transient_nlos_path import TransientNLOSPath

    doc = TransientNLOSPath.__doc__
    assert ".. list-table::" in doc
    for name in ("max_depth", "rr_depth", "variance_replicates", "rqmc", "hidden_geometry_prob"):
        assert f"* - ``{name}``" in doc, name
    assert "three-bounce" in doc  # max_depth = 4 explained in NLOS terms


def test_a_camera_sensor_is_refused_with_one_line_naming_it():
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "transient_nlos_path"},
        "cam": {"type": "perspective", "id": "cam0",
                "film": {"type": "transient_film", "width": 4, "height": 4, "n_bins": 10}}})
    with pytest.raises(PluginParameterError) as info:
        scene.integrator().render_transient(scene, scene.sensors()[0], spp=2)
    msg = str(info.value)
    assert msg == ("transient_nlos_path: the sensor PerspectiveCamera 'cam0' is not an NLOS sensor; "
                   "transient_nlos_path renders spad_array captures (use transient_path for cameras)")


@pytest.mark.parametrize("capture", ["array", "confocal"])
def test_transient_path_under_a_spad_array_gives_the_same_bytes(capture):
    """``transient_path`` delegates to the NLOS estimator: same seed, same bytes (histogram, variance, steady)."""
    kw = dict(width=4, height=3, hidden=HIDDEN, spots=(2, 1), spacing=0.1, capture=capture, **WINDOW)
    old = nlos_scene(integrator="transient_path", **kw)
    new = nlos_scene(integrator="transient_nlos_path", **kw)
    assert type(old.integrator()).__name__ == "TransientPath"
    assert type(new.integrator()).__name__ == "TransientNLOSPath"
    results = []
    for sc in (old, new):
        sc.integrator().variance_replicates = 4
        calls = [dict(spot=0)] + ([dict(spots=[0, 1])] if capture == "array" else [])
        out = []
        for call in calls:
            r = sc.integrator().render_transient(sc, sc.sensors()[0], seed=7, spp=32, **call)
            out += r if isinstance(r, list) else [r]
        results.append(out)
    assert results[0][0].histogram.sum() > 0  # the window holds light: the comparison is not of zeros
    for a, b in zip(*results):
        for field in ("histogram", "variance", "steady", "total_variance"):
            assert getattr(a, field).tobytes() == getattr(b, field).tobytes(), field
        assert (a.dropped_contributions, a.replicates) == (b.dropped_contributions, b.replicates)


def test_mi_render_returns_the_film_histogram():
    sc = nlos_scene(width=3, height=2, hidden=HIDDEN, **WINDOW)
    img = np.asarray(mi.render(sc, spp=4))
    assert img.shape == (2, 3, WINDOW["n_bins"])
    assert np.array_equal(img, sc.sensors()[0].film().result.histogram)


def test_one_lane_policy_gives_the_stream_counts_of_both_former_rules():
    """``_lanes.streams_for`` replaced two loops (cameras: ``choose_streams``; NLOS groups: ``group_layout``);
    the stream count K, and so every byte, must be what the former rules gave, in every case, the memory cap
    binding or not."""
    from transient_mi.integrators._lanes import (CAMERA_TARGET_LANES_CUDA, CAMERA_TARGET_LANES_LLVM, MAX_SLOT_FLOATS,
                                                 NLOS_GROUP_TARGET_LANES, choose_streams, is_cuda)
    from transient_mi.integrators._nlos_render import group_layout

    camera_target = CAMERA_TARGET_LANES_CUDA if is_cuda() else CAMERA_TARGET_LANES_LLVM  # (the variant's backend)

    def camera_before(P, spp, T):
        k = 1
        while k * 2 <= spp and P * k * 2 <= camera_target and P * k * 2 * T <= MAX_SLOT_FLOATS:
            k *= 2
        return k

    def nlos_before(P, spp):
        k = 1
        while k * 2 <= spp and P * k * 2 <= NLOS_GROUP_TARGET_LANES:
            k *= 2
        return k

    assert (CAMERA_TARGET_LANES_LLVM, NLOS_GROUP_TARGET_LANES, MAX_SLOT_FLOATS) == (1 << 15, 1 << 10, 1 << 28)
    for P in (1, 3, 16, 100, 1024, 4096, 1 << 15, 1 << 17):
        for spp in (1, 2, 7, 64, 1000, 1 << 16):
            for T in (1, 48, 1500, 1 << 14, 1 << 18, (1 << 20) + 40):
                if P * T <= MAX_SLOT_FLOATS:  # (both rules raise MemoryError beyond)
                    assert choose_streams(P, spp, T) == camera_before(P, spp, T), (P, spp, T)
                assert group_layout(P, spp, T, 8)[0] == nlos_before(P, spp), (P, spp, T)


def test_a_rendered_nlos_scene_is_freed_when_dropped():
    """The sensor's cached scene analysis keeps no reference to the scene (a cycle through C++ objects that
    the garbage collector cannot see): once the user drops a rendered scene, its laser is freed. A leaked
    scene slowed every later render (Dr.Jit traced its Python plug-ins in every call over emitters)."""
    import gc

    from transient_mi.emitters.pulsed_laser import PulsedLaser

    def live_lasers():
        gc.collect()
        return sum(isinstance(o, PulsedLaser) for o in gc.get_objects())

    before = live_lasers()
    scene = nlos_scene(hidden=[square((0.0, 0.0, 0.5), 0.2, 0.5)], spp=4)
    scene.integrator().render_transient(scene, scene.sensors()[0], seed=1, spp=4)
    assert live_lasers() == before + 1
    del scene
    assert live_lasers() == before
