"""NLOS previews show the hidden scene: the wall's own return is excluded from the image and the streak and drawn
on its own axis, with linear axes (no log axis down to the 1e-30 floor)."""

from __future__ import annotations

import copy

import numpy as np

from recon.synthetic import point_capture
from transient_mi.preview import wall_return_mask, write_preview

C_M_PER_PS = 299792458.0e-12


def _capture_with_wall_return():
    cap = point_capture([[0.0, 0.0, 0.4]], mode="confocal", pixels=4, wall_size_m=0.4, sigma_ps=20, bin_width_ps=8,
                        include_first_last=True)
    m = copy.deepcopy(cap.manifest)
    m["geometry"]["include_wall_return"] = True
    g, t = m["geometry"], m["time"]
    data = np.array(cap.data[0], dtype=np.float64)  # [y, x, t] (confocal: one file)
    P = np.asarray(g["pixel_centers"]).reshape(4, 4, 3)
    L, D = np.asarray(g["laser_origin"]), np.asarray(g["detector_origin"])
    t_wall = (np.linalg.norm(P - L, axis=-1) + np.linalg.norm(P - D, axis=-1)) / C_M_PER_PS  # laser spot = pixel
    k = int(np.ceil((t["t0_ps"] - t_wall.min()) / t["bin_width_ps"])) + 10  # bins added before the hidden light
    m["time"] = dict(t, t0_ps=t["t0_ps"] - k * t["bin_width_ps"], n_bins=t["n_bins"] + k)
    t = m["time"]
    full = np.zeros((4, 4, t["n_bins"]))
    full[..., k:] = data
    wall_bins = ((t_wall - t["t0_ps"]) // t["bin_width_ps"]).astype(int)
    for (y, x), b in np.ndenumerate(wall_bins):
        full[y, x, b] = 1e6 * data.max()  # the first bounce: orders of magnitude brighter
    return m, full, wall_bins


def test_wall_return_mask_covers_the_first_bounce_and_not_the_hidden_light():
    m, full, wall_bins = _capture_with_wall_return()
    mask = wall_return_mask(m, 0, full.shape)
    for (y, x), b in np.ndenumerate(wall_bins):
        assert mask[y, x, b]
    hidden = full.copy()
    for (y, x), b in np.ndenumerate(wall_bins):
        hidden[y, x, b] = 0
    assert not np.any(mask & (hidden > 0))  # every bin of the 0.4 m deep point's light is kept
    m2 = copy.deepcopy(m)
    m2["geometry"]["include_wall_return"] = False
    assert not wall_return_mask(m2, 0, full.shape).any()


def test_preview_draws_the_hidden_light_on_linear_axes(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    m, full, _ = _capture_with_wall_return()
    figs = []
    orig = Figure.savefig

    def keep(self, *a, **k):
        figs.append(self)
        return orig(self, *a, **k)

    monkeypatch.setattr(Figure, "savefig", keep)
    write_preview(tmp_path / "preview.png", full, m)
    assert (tmp_path / "preview.png").stat().st_size > 1000
    axes = figs[0].axes
    image_max = axes[0].images[0].get_array().max()
    assert image_max < 1e-3 * full.max()  # the image shows the hidden light, not the wall return
    plots = [a for a in axes if a.lines]
    assert all(a.get_yscale() == "linear" for a in plots)
    assert any("wall return (own scale)" in a.get_ylabel() for a in plots)


def test_camera_preview_of_an_rgb_capture_is_in_colour(tmp_path, monkeypatch):
    """An R, G, B camera capture's time-integrated image and time slices are drawn in colour: a pixel that is
    red in the data is red in the picture (its R above its G and B)."""
    from matplotlib.figure import Figure

    from transient_core import stack

    H, W, T = 6, 8, 20
    rgb = np.zeros((H, W, T, 3), np.float32)
    rgb[:, : W // 2, 5:15, 0] = 1.0  # left half red
    rgb[:, W // 2:, 5:15, 1] = 1.0  # right half green
    m = stack.new_manifest(kind="ideal", capture="camera", width=W, height=H, n_files=1, t0_ps=0.0,
                           bin_width_ps=10.0, n_bins=T, quantity="radiance", channels=("R", "G", "B"))
    figs = []
    orig = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: (figs.append(self), orig(self, *a, **k))[1])
    write_preview(tmp_path / "preview.png", stack.intensity(rgb, m), m, rgb=rgb)
    for ax in figs[0].axes[:5]:  # time-integrated image and four slices
        img = np.asarray(ax.images[0].get_array())
        assert img.shape == (H, W, 3)
        left, right = img[H // 2, 1], img[H // 2, W - 2]
        assert left[0] > 0.5 and left[1] == 0 and right[1] > 0.5 and right[0] == 0
