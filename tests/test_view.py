"""``transient-mi view`` and ``transient-mi video``: data discovery, confinement to the viewed path, the
detector and reconstruction computations behind the panels, videos, and the page in a real headless
browser (Chromium driven by Playwright; the test starts and stops the server and the browser).

Nothing here is statistical: counts are compared bit for bit with ``transient-mi detect``'s (same seed
rule), so no false-failure rate applies.
"""

from __future__ import annotations

import http.client
import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from view_helpers import camera_capture, ideal_capture, view_tree

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    root = view_tree(tmp_path_factory.mktemp("view") / "data")
    camera_capture(root / "camera")
    return root


# ----------------------------------------------------------------- data and confinement


def test_discover_finds_captures_recons_and_the_ground_truth(tree):
    from transient_view.data import discover

    lib = discover(tree)
    assert [lib.label(p) for p in lib.captures] == ["camera", "counts", "ideal"]
    assert [lib.label(p) for p in lib.recons] == ["recon_bp"]
    gt = tree.resolve() / "ground_truth.ply"
    assert lib.ground_truth_for(tree.resolve() / "ideal") == gt
    assert lib.ground_truth_for(tree.resolve() / "recon_bp") == gt
    assert lib.recon_capture(tree.resolve() / "recon_bp") == tree.resolve() / "ideal"


def test_resolve_refuses_every_way_out_of_the_viewed_path(tree, tmp_path):
    from transient_view.data import discover

    secret = tmp_path / "secret.txt"
    secret.write_text("not for the viewer")
    link = tree / "escape.txt"
    link.symlink_to(secret)
    try:
        lib = discover(tree)
        assert lib.resolve("ideal/manifest.json") == (tree / "ideal" / "manifest.json").resolve()
        for bad in ("../secret.txt", "ideal/../../secret.txt", str(secret), "/etc/passwd", "escape.txt",
                    "ideal", "nonexistent.json", "ideal/\x00manifest.json"):
            with pytest.raises(PermissionError):
                lib.resolve(bad)
    finally:
        link.unlink()


def test_a_single_file_root_allows_only_itself(tree, tmp_path):
    from recon import load_capture, write_ytal

    from transient_view.data import discover

    h5 = write_ytal(load_capture(tree / "ideal"), tmp_path / "c.h5")
    (tmp_path / "other.txt").write_text("x")
    lib = discover(h5)
    assert lib.captures == [h5.resolve()]
    assert lib.resolve("c.h5") == h5.resolve()
    with pytest.raises(PermissionError):
        lib.resolve("other.txt")


def test_bad_paths_are_one_line_errors(tmp_path):
    r = subprocess.run([sys.executable, "-m", "transient_mi", "view", str(tmp_path / "nope"), "--no-browser"],
                       capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 2 and r.stderr.startswith("error: PATH") and "Traceback" not in r.stderr
    (tmp_path / "empty").mkdir()
    r = subprocess.run([sys.executable, "-m", "transient_mi", "view", str(tmp_path / "empty"), "--no-browser"],
                       capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 2 and "holds no capture" in r.stderr and "Traceback" not in r.stderr


def test_the_core_install_does_not_import_the_viewer_libraries():
    code = ("import sys, transient_mi.cli, transient_mi.commands.view, transient_mi.commands.video; "
            "bad = [m for m in ('bokeh', 'tornado', 'playwright', 'imageio_ffmpeg') if m in sys.modules]; "
            "print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stdout + r.stderr


# ------------------------------------------------------------------- panel computations


def test_detector_panel_counts_equal_transient_mi_detect(tree, tmp_path):
    """The live counts are the ones ``detect_stack`` writes for the same parameters, pulses and seed."""
    from transient_core.stack import read_spot

    from spad_detector import DetectorParams, detect_stack
    from transient_view.data import CaptureData
    from transient_view.detector_panel import simulate_counts

    params = DetectorParams(pde=0.5, jitter_ps=60.0, dead_time_ns=5.0, gate_open_ps=2500.0, gate_close_ps=5000.0)
    out = detect_stack(tree / "ideal", tmp_path / "c", params, pulses=200_000, seed=0, engine="analytic",
                       progress=False)
    data = CaptureData(tree / "ideal")
    for j in (0, 3):
        counts, info, run = simulate_counts(data.spot(j), data, params, 200_000, spot=j, seed=0)
        np.testing.assert_array_equal(counts, read_spot(out, j))
    assert run.gate_open_ps == 2500.0 and info["engine"] == "analytic"


def test_detector_panel_auto_gate_matches_detect_per_spot_gates(tree, tmp_path):
    from transient_core.stack import read_manifest

    from spad_detector import DetectorParams, detect_stack
    from transient_view.data import CaptureData
    from transient_view.detector_panel import simulate_counts

    params = DetectorParams(auto_gate=True, auto_gate_depth_min_m=0.2)
    out = detect_stack(tree / "ideal", tmp_path / "g", params, pulses=1000, engine="analytic", progress=False)
    res = read_manifest(out)["detector"]["resolved"]
    data = CaptureData(tree / "ideal")
    _, _, run = simulate_counts(data.spot(2), data, params, 1000, spot=2)
    assert (run.gate_open_ps, run.gate_close_ps) == (res["gate_open_ps_per_spot"][2], res["gate_close_ps_per_spot"][2])


def test_counts_capture_finds_its_ideal_capture_for_the_detector_panel(tree):
    from transient_view.data import CaptureData, discover

    lib = discover(tree)
    ideal = CaptureData(tree / "counts").ideal_source(lib)
    assert ideal is not None and ideal.path == (tree / "ideal").resolve()
    assert CaptureData(tree / "camera").ideal_source(lib) is None


def test_projection_of_the_3d_view():
    from transient_view.recon_panel import project_points

    rng = np.random.default_rng(0)
    p = rng.normal(size=(50, 3))
    c = np.array([0.1, -0.2, 0.5])
    np.testing.assert_allclose(project_points(p, c, 0, 0), p - c, atol=1e-12)
    q = project_points(p, c, 37, -22)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), np.linalg.norm(p - c, axis=1), rtol=1e-12)
    # azimuth 90 deg: looking along -x, so screen u is -z (orthographic, right-handed)
    np.testing.assert_allclose(project_points(np.array([[0, 0, 1.0]]), np.zeros(3), 90, 0), [[-1, 0, 0]],
                               atol=1e-12)


def test_every_panel_builds_headless_for_each_item(tree):
    """The page for every item of the tree, built in a Bokeh document without a browser."""
    from bokeh.document import Document

    from transient_view.app import Page
    from transient_view.data import discover

    lib = discover(tree)
    page = Page(lib, Document())
    for i, (kind, p) in enumerate(page.items):
        page.show(i)
        page.open_tab("Detector")
        page.open_tab("Reconstruction")
        for name, panel in page.panels.items():
            assert "color:#b00" not in panel.status.div.text, (kind, p, name, panel.status.div.text)
        expected = {"camera": {"capture"}, "counts": {"capture", "detector", "recon"},
                    "ideal": {"capture", "detector", "recon"}, "recon_bp": {"capture", "detector", "recon"}}
        assert set(page.panels) == expected[p.name]


# ---------------------------------------------------------------------------- video


def test_gif_has_one_frame_per_bin_with_the_expected_size(tmp_path):
    from PIL import Image

    from transient_view.video import BANNER_PX, write_video

    cap = ideal_capture(tmp_path / "c", pixels=8, spots=1, n_bins=40)
    info = write_video(cap, tmp_path / "v.gif", stride=3, first_bin=1, scale=5)
    im = Image.open(tmp_path / "v.gif")
    assert im.n_frames == info["n_frames"] == len(range(1, 40, 3))
    assert im.size == (info["width"], info["height"])
    assert info["height"] == 8 * 5 + BANNER_PX and info["width"] >= 8 * 5  # widened for the time stamp
    info = write_video(cap, tmp_path / "w.gif", scale=40)
    assert Image.open(tmp_path / "w.gif").size == (8 * 40, 8 * 40 + BANNER_PX)
    assert not list(tmp_path.glob(".*tmp*"))  # nothing half-written left behind


def test_mp4_has_the_expected_frames_and_size(tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg is in the view extra")
    from transient_view.video import write_video

    cap = ideal_capture(tmp_path / "c", pixels=8, spots=1, n_bins=30)
    info = write_video(cap, tmp_path / "v.mp4", fps=10)
    n, _ = imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "v.mp4"))
    assert n == info["n_frames"] == 30
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "v.mp4"))
    meta = next(reader)
    reader.close()
    assert tuple(meta["size"]) == (info["width"], info["height"]) and info["width"] % 16 == 0


def test_video_command_and_its_errors(tmp_path, monkeypatch):
    cap = ideal_capture(tmp_path / "c", pixels=4, spots=1, n_bins=12)
    run = lambda *a: subprocess.run([sys.executable, "-m", "transient_mi", "video", *map(str, a)],  # noqa: E731
                                    capture_output=True, text=True, cwd=REPO)
    r = run(cap, "-o", tmp_path / "a.gif", "--fps", "5")
    assert r.returncode == 0 and "12 frames" in r.stdout, r.stderr
    for args, msg in (((cap, "-o", tmp_path / "a.avi"), "suffix must be one of .gif, .mp4"),
                      ((cap, "-o", tmp_path / "b.gif", "--spot", "3"), "--spot 3: this capture has spots 0..0"),
                      ((cap, "-o", tmp_path / "b.gif", "--fps", "0"), "--fps 0.0: must be a number > 0"),
                      ((cap, "-o", tmp_path / "b.gif", "--last-bin", "99"), "--last-bin 99")):
        r = run(*args)
        assert r.returncode == 2 and r.stderr.startswith("error: ") and msg in r.stderr, r.stderr
        assert "Traceback" not in r.stderr
    assert not (tmp_path / "b.gif").exists()


def test_mp4_without_imageio_ffmpeg_is_refused_clearly(tmp_path, monkeypatch):
    from transient_core.errors import UserInputError

    from transient_view.video import write_video

    cap = ideal_capture(tmp_path / "c", pixels=4, spots=1, n_bins=12)
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    with pytest.raises(UserInputError, match=r"MP4 needs imageio-ffmpeg; install the viewer extra"):
        write_video(cap, tmp_path / "v.mp4")
    assert not (tmp_path / "v.mp4").exists()


# ------------------------------------------------------------------ the page in a browser


def _start_server(path, *extra):
    proc = subprocess.Popen([sys.executable, "-m", "transient_mi", "view", str(path), "--no-browser", "--port", "0",
                             *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    line = proc.stdout.readline()
    if not line.startswith("serving at "):
        proc.kill()
        raise AssertionError(f"server did not start: {line!r} {proc.stderr.read()}")
    return proc, line.split()[2]


def _stop(proc) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("Playwright is not installed (pip install 'transient-mi[test,view]')")
    if not os.path.exists(CHROMIUM):
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium; .ci/run installs it)")
    pw = sync_playwright().start()
    b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
    yield b
    b.close()
    pw.stop()


@pytest.fixture(scope="module")
def server(tree):
    proc, url = _start_server(tree)
    yield url
    _stop(proc)


def _open(browser, url, show: str):
    from urllib.parse import quote

    page = browser.new_page(viewport={"width": 1500, "height": 1100})
    page.goto(f"{url}?show={quote(show)}")
    page.wait_for_function("() => window.Bokeh && Bokeh.documents.length > 0 && "
                           "Bokeh.documents[0].get_model_by_name('tabs') !== null", timeout=30000)
    return page


def _status(page, name: str) -> str:
    return page.evaluate(f"() => Bokeh.documents[0].get_model_by_name('{name}').text")


def _count(text: str) -> int:
    return int(text.split("#", 1)[1].split(":", 1)[0])


def _wait_status(page, name: str, above: int, timeout_ms: int = 30000) -> str:
    page.wait_for_function(
        f"() => {{ const m = Bokeh.documents[0].get_model_by_name('{name}'); "
        f"return m !== null && parseInt(m.text.split('#')[1]) > {above}; }}", timeout=timeout_ms)
    page.wait_for_timeout(300)  # let the canvas repaint
    return _status(page, name)


def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=np.float64)


def _assert_not_blank(png: bytes, what: str) -> None:
    """Content, not an empty canvas: at least 5 % of the pixels differ from the most common (background)
    grey level, and the grey levels spread (standard deviation > 10 of 255)."""
    a = _pixels(png)
    values, counts = np.unique(a.round(), return_counts=True)
    background = values[np.argmax(counts)]
    frac = float(np.mean(np.abs(a - background) > 8))
    assert frac > 0.05 and a.std() > 10, f"{what} looks blank ({frac:.3f} non-background, std {a.std():.1f})"


def _changed(a: bytes, b: bytes) -> float:
    pa, pb = _pixels(a), _pixels(b)
    assert pa.shape == pb.shape
    return float(np.mean(np.abs(pa - pb) > 8))


def test_page_loads_and_each_panel_renders(browser, server, tmp_path):
    page = _open(browser, server, "capture: ideal")
    try:
        assert page.title() == "transient-mi view: data"
        assert "error" not in _status(page, "capture_status")
        for name in ("integrated_image", "slice_image", "xt_image", "yt_image", "pixel_hist", "wall_figure"):
            _assert_not_blank(page.locator(f".tmv-{name}").screenshot(), name)
        facts = page.evaluate("() => Bokeh.documents[0].get_model_by_name('manifest_facts').text")
        assert "256 x 16 ps from t0 = 2000 ps" in facts and "37.5 mm" in facts
        page.locator(".bk-tab", has_text="Detector").click()
        _wait_status(page, "detector_status", 0)
        for name in ("counts_image", "ideal_hist", "counts_hist"):
            _assert_not_blank(page.locator(f".tmv-{name}").screenshot(), name)
        page.locator(".bk-tab", has_text="Reconstruction").click()
        _wait_status(page, "recon_status", 0)
        _wait_status(page, "metrics_status", 0)
        for name in ("mip_z", "mip_y", "mip_x", "depth_map", "view3d"):
            _assert_not_blank(page.locator(f".tmv-{name}").screenshot(), name)
        metrics = page.evaluate("() => Bokeh.documents[0].get_model_by_name('metrics_table').text")
        assert "chamfer_m" in metrics and "ground_truth.ply" in metrics
        if os.environ.get("TRANSIENT_MI_VIEW_SCREENSHOTS"):  # docs/img/ pictures (see docs/view.md)
            out = Path(os.environ["TRANSIENT_MI_VIEW_SCREENSHOTS"])
            page.screenshot(path=str(out / "view_reconstruction.png"))
            page.locator(".bk-tab", has_text="Capture").click()
            page.wait_for_timeout(800)
            page.screenshot(path=str(out / "view_capture.png"))
    finally:
        page.close()


def test_time_slider_changes_the_image(browser, server):
    page = _open(browser, server, "capture: ideal")
    try:
        n0 = _count(_status(page, "capture_status"))
        before = page.locator(".tmv-slice_image").screenshot()
        bin0 = page.evaluate("() => Bokeh.documents[0].get_model_by_name('time_slider').value")
        handle = page.locator(".time-slider .noUi-handle")
        handle.focus()
        for _ in range(4):
            handle.press("ArrowRight")
        _wait_status(page, "capture_status", n0 + 3)  # one server update per key press
        bin1 = page.evaluate("() => Bokeh.documents[0].get_model_by_name('time_slider').value")
        assert bin1 == bin0 + 4 and _status(page, "capture_status").endswith(f"bin {bin1}")
        after = page.locator(".tmv-slice_image").screenshot()
        assert _changed(before, after) > 0.02
    finally:
        page.close()


def test_clicking_a_pixel_shows_its_histogram(browser, server):
    page = _open(browser, server, "capture: ideal")
    try:
        n0 = _count(_status(page, "capture_status"))
        before = page.locator(".tmv-pixel_hist").screenshot()
        # a point in the left part of the image (away from the default centre pixel)
        box = page.locator(".tmv-integrated_image canvas").first.bounding_box()
        page.mouse.click(box["x"] + 0.3 * box["width"], box["y"] + 0.7 * box["height"])
        text = _wait_status(page, "capture_status", n0)
        assert "pixel (" in text
        assert _changed(before, page.locator(".tmv-pixel_hist").screenshot()) > 0.005
    finally:
        page.close()


def test_photon_budget_changes_the_counts_histogram(browser, server):
    page = _open(browser, server, "capture: ideal")
    try:
        page.locator(".bk-tab", has_text="Detector").click()
        first = _wait_status(page, "detector_status", 0)
        assert first.split(": ", 1)[1].startswith("1e+06 pulses")
        before = page.locator(".tmv-counts_hist").screenshot()
        handle = page.locator(".budget-slider .noUi-handle")
        handle.focus()
        for _ in range(10):  # 10 steps of 0.1 in log10(pulses): one decade fewer
            handle.press("ArrowLeft")
        page.wait_for_function("() => /#[0-9]+: 1e\\+05 pulses/.test("
                               "Bokeh.documents[0].get_model_by_name('detector_status').text)", timeout=30000)
        page.wait_for_timeout(300)
        text = _status(page, "detector_status")
        n_before = int(first.split(": ", 2)[2].split(" counts")[0].replace(",", ""))
        n_after = int(text.split(": ", 2)[2].split(" counts")[0].replace(",", ""))
        # ten times fewer pulses: about ten times fewer counts (Poisson spread of ~5e4 counts is < 1 %)
        assert 0.05 < n_after / n_before < 0.2, (first, text)
        assert _changed(before, page.locator(".tmv-counts_hist").screenshot()) > 0.005
    finally:
        page.close()


def test_another_recon_method_updates_the_projections(browser, server):
    page = _open(browser, server, "capture: ideal")
    try:
        page.locator(".bk-tab", has_text="Reconstruction").click()
        n = _count(_wait_status(page, "recon_status", 0))
        before = page.locator(".tmv-mip_z").screenshot()
        page.locator(".method-select select").select_option("phasor")
        text = _wait_status(page, "recon_status", n)
        assert text.split(": ", 1)[1].startswith("phasor on 32x32x32 voxels"), text
        assert _changed(before, page.locator(".tmv-mip_z").screenshot()) > 0.02
    finally:
        page.close()


def test_stored_reconstruction_and_counts_capture_pages(browser, server):
    for show in ("recon: recon_bp", "capture: counts", "capture: camera"):
        page = _open(browser, server, show)
        try:
            assert page.evaluate("() => Bokeh.documents[0].get_model_by_name('load_error')") is None
            _assert_not_blank(page.locator(".tmv-integrated_image").screenshot(), f"{show} integrated image")
        finally:
            page.close()


def _get(url: str, raw_path: str) -> tuple[int, bytes]:
    host, port = url.split("//")[1].rstrip("/").split(":")
    c = http.client.HTTPConnection(host, int(port), timeout=10)
    c.putrequest("GET", raw_path, skip_host=False, skip_accept_encoding=True)
    c.endheaders()
    r = c.getresponse()
    body = r.read()
    c.close()
    return r.status, body


def test_files_outside_the_path_are_refused(server, tree):
    status, body = _get(server, "/files/ideal/manifest.json")
    assert status == 200 and body == (tree / "ideal" / "manifest.json").read_bytes()
    for raw in ("/files/../../../../etc/passwd", "/files/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
                "/files/ideal/..%2f..%2f..%2fetc%2fpasswd", "/files/%2fetc%2fpasswd", "/files//etc/passwd",
                "/files/ideal", "/static/../../../../etc/passwd", "/files/..%5c..%5cetc%5cpasswd"):
        status, body = _get(server, raw)
        assert status in (403, 404), (raw, status)
        assert b"root:" not in body


def test_server_binds_to_localhost_by_default(server):
    assert server.startswith("http://127.0.0.1:")


# --------------------------------------------------- embedded scenes and the demo output


@pytest.fixture(scope="module")
def scene_captures(tmp_path_factory):
    """Every embedded scene rendered small (in this process; a few seconds each)."""
    from transient_mi.render_capture import prepare_render, run_render

    root = tmp_path_factory.mktemp("scenes")
    nlos = {"width": "4", "height": "4", "spots_x": "2", "spots_y": "1"}  # 512 bins: the hidden objects arrive late
    settings = {
        "cornell_box": {"width": "8", "height": "6", "n_bins": "60"},
        "fog_camera": {"width": "8", "height": "6", "n_bins": "60"},
        "nlos_letter": nlos, "nlos_point_targets": nlos, "nlos_tilted_plane": nlos, "fog_nlos": nlos,
        "glass_window_nlos": nlos,
        "paper_mannequin": {"array": "4", "spots": "1", "n_bins": "1500", "bin_width_ps": "8", "estimator": "monte_carlo"},
    }
    assert sorted(settings) == sorted(p.stem for p in (REPO / "scenes").glob("*.xml"))
    for name, defines in settings.items():
        job = prepare_render(REPO / "scenes" / f"{name}.xml", root / name, defines=defines, spp=16, seed=0)
        run_render(job, progress=False)
    return root


def test_viewer_works_on_every_embedded_scene(browser, scene_captures):
    proc, url = _start_server(scene_captures)
    try:
        for name in sorted(p.name for p in scene_captures.iterdir()):
            page = _open(browser, url, f"capture: {name}")
            try:
                assert "color:#b00" not in _status(page, "capture_status")
                _assert_not_blank(page.locator(".tmv-integrated_image").screenshot(), name)
                if name in ("cornell_box", "fog_camera"):
                    continue  # a camera capture: no detector or reconstruction (told on the page)
                page.locator(".bk-tab", has_text="Detector").click()
                assert "color:#b00" not in _wait_status(page, "detector_status", 0), name
                page.locator(".bk-tab", has_text="Reconstruction").click()
                assert "color:#b00" not in _wait_status(page, "recon_status", 0), name
                _assert_not_blank(page.locator(".tmv-mip_z").screenshot(), f"{name} projection")
            finally:
                page.close()
    finally:
        _stop(proc)


def test_viewer_works_on_the_demo_output(browser, tmp_path):
    from transient_mi.demo import DemoSettings, run_demo
    from transient_view.data import discover

    s = DemoSettings(arrays=(4, 8), spp=8, bin_width_ps=16.0, n_bins=720, voxels=(16, 16, 8))
    out = run_demo(tmp_path / "demo", settings=s, progress=False, log=lambda *a: None)
    lib = discover(out)
    labels = [lib.label(p) for p in lib.captures + lib.recons]
    assert labels == ["captures/array_04/counts", "captures/array_04/ideal", "captures/array_08/counts",
                      "captures/array_08/ideal", "recon/array_04", "recon/array_08",
                      "recon/array_08_midpoint-fk",  # the demo's best array method on its largest array
                      "recon/array_08_midpoint-fk_completed"]  # and that closed behind its front (recon.completion)
    gt = (out / "ground_truth.ply").resolve()
    assert all(lib.ground_truth_for(p) == gt for p in lib.captures + lib.recons)
    proc, url = _start_server(out)
    try:
        for show in ("capture: captures/array_08/counts", "recon: recon/array_08",
                     "recon: recon/array_08_midpoint-fk_completed"):
            page = _open(browser, url, show)
            try:
                _assert_not_blank(page.locator(".tmv-integrated_image").screenshot(), show)
                page.locator(".bk-tab", has_text="Detector").click()  # the counts' ideal capture
                assert "color:#b00" not in _wait_status(page, "detector_status", 0)
                page.locator(".bk-tab", has_text="Reconstruction").click()
                assert "color:#b00" not in _wait_status(page, "recon_status", 0)
                _wait_status(page, "metrics_status", 0)
                _assert_not_blank(page.locator(".tmv-view3d").screenshot(), f"{show} 3-D view")
            finally:
                page.close()
    finally:
        _stop(proc)
