"""Multi-channel captures (colour, Stokes vectors): one EXR layer per time bin, exact round trips,
one intensity per bin for the detector and recon, clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from transient_core import stack


def _manifest(channels, kind="ideal", T=5, H=3, W=4, **kw):
    return stack.new_manifest(kind=kind, capture="camera", width=W, height=H, n_files=1, t0_ps=0.0,
                              bin_width_ps=10.0, n_bins=T, quantity="radiance", channels=channels, **kw)


@pytest.mark.parametrize("channels", [("R", "G", "B"), ("S0", "S1", "S2", "S3"), ("400-500nm", "500-700nm")])
def test_round_trip_is_bit_exact_with_one_layer_per_bin(tmp_path, channels):
    import OpenEXR

    m = _manifest(channels)
    rng = np.random.default_rng(1)
    a = rng.random((1, 3, 4, 5, len(channels)), dtype=np.float32)
    stack.write_stack(tmp_path / "c", m, a)
    m2, b = stack.read_stack(tmp_path / "c")
    assert b.shape == (1, 3, 4, 5, len(channels)) and a.tobytes() == b.tobytes()
    assert m2["channels"] == list(channels)
    # the file holds layers tNNNNN with sub-channels, readable by any layer-aware EXR tool
    names = set(OpenEXR.File(str(tmp_path / "c" / "spot_00000.exr"), separate_channels=True).channels())
    assert names == {f"t{b:05d}.{c}" for b in range(5) for c in channels}


def test_variance_of_a_multichannel_capture_round_trips(tmp_path):
    m = _manifest(("R", "G", "B"), variance={"directory": "variance", "replicates": 8})
    d = tmp_path / "v"
    d.mkdir()
    rng = np.random.default_rng(2)
    var = rng.random((3, 4, 5, 3), dtype=np.float32)
    tot = rng.random((3, 4, 3), dtype=np.float32)
    stack.write_variance(d, 0, var, tot, m)
    v2, t2 = stack.read_variance(d, 0, m)
    assert v2.tobytes() == var.tobytes() and t2.tobytes() == tot.tobytes()


def test_intensity_rules():
    rgb = np.zeros((1, 1, 2, 3), np.float32)
    rgb[..., 0, :] = [1.0, 0.0, 0.0]
    rgb[..., 1, :] = [1.0, 1.0, 1.0]
    y = stack.intensity(rgb, _manifest(("R", "G", "B")))
    assert y.shape == (1, 1, 2)
    assert y[0, 0, 0] == pytest.approx(0.212671, rel=1e-6)
    assert y[0, 0, 1] == pytest.approx(1.0, rel=1e-6)  # Rec. 709 weights sum to 1: grey keeps its value
    stokes = np.arange(8, dtype=np.float32).reshape(1, 1, 2, 4)
    assert np.array_equal(stack.intensity(stokes, _manifest(("S0", "S1", "S2", "S3"))), stokes[..., 0])
    mono = np.ones((1, 1, 2), np.float32)
    assert stack.intensity(mono, _manifest(None)) is mono
    bands = np.array([[[[1.0, 2.0, 4.0]]]], np.float32)
    m = _manifest(("400-500nm", "500-600nm", "650-700nm"))
    assert m["intensity"] == "sum" and stack.intensity(bands, m)[0, 0, 0] == 7.0


@pytest.mark.parametrize("channels, kind, match", [
    (("R", "G"), "ideal", "channels="),
    (("X", "Y", "Z"), "ideal", "channels="),
    (("500-600nm", "400-500nm"), "ideal", "wavelength bands"),  # not increasing
    (("400-550nm", "500-600nm"), "ideal", "wavelength bands"),  # overlapping
    (("400.5-500nm",), "ideal", "wavelength bands"),  # a dot would split the EXR layer name
    (("400-500nm",), "counts", "counts capture has one intensity"),
    (("R", "G", "B"), "counts", "counts capture has one intensity"),
])
def test_bad_channel_sets_are_refused(channels, kind, match):
    with pytest.raises(stack.StackError, match=match):
        _manifest(channels, kind=kind)


def test_mono_reader_refuses_a_multichannel_file_and_names_it(tmp_path):
    m = _manifest(("R", "G", "B"))
    stack.write_stack(tmp_path / "c", m, np.zeros((1, 3, 4, 5, 3), np.float32))
    mono = dict(m)
    mono.pop("channels")
    mono.pop("intensity")
    with pytest.raises(stack.StackError, match=r"spot_00000.exr: header tmi_channels='R,G,B'"):
        stack.read_spot(tmp_path / "c", 0, mono)
    with pytest.raises(stack.StackError, match=r"data shape"):
        stack.write_spot(tmp_path / "c", 0, np.zeros((3, 4, 5), np.float32), m)


def test_detector_and_recon_use_the_intensity_of_a_multichannel_capture(tmp_path):
    """An RGB ideal capture is detected and reconstructed from its luminance: the same counts, byte for byte,
    as the mono capture holding that luminance (same seed), and the counts manifest says which intensity."""
    from detector_helpers import make_ideal_capture

    import recon
    from spad_detector import detect_stack

    rng = np.random.default_rng(3)
    rgb = rng.random((2, 3, 4, 64, 3), dtype=np.float32) * 1e-4
    make_ideal_capture(tmp_path / "rgb", rgb, bin_width_ps=16.0, channels=("R", "G", "B"))
    y = stack.intensity(rgb, {"channels": ["R", "G", "B"], "intensity": "luminance"})
    make_ideal_capture(tmp_path / "mono", y, bin_width_ps=16.0)
    for name in ("rgb", "mono"):
        detect_stack(tmp_path / name, tmp_path / f"{name}_counts", pulses=100_000, seed=5, progress=False,
                     warn=False)
    m, c_rgb = stack.read_stack(tmp_path / "rgb_counts")
    _, c_mono = stack.read_stack(tmp_path / "mono_counts")
    assert m["detected_intensity"] == "luminance" and "channels" not in m
    assert c_rgb.tobytes() == c_mono.tobytes()
    cap = recon.load_capture(tmp_path / "rgb")
    assert np.array_equal(cap.spot(1), y[1])
