"""Kill -9 at named points (``TRANSIENT_MI_FAULT``, :mod:`transient_core.fault`), then rerun or ``--resume``.

For every command that writes (render: NLOS array, ``--noise-target``, camera, fog, quadrature; detect, recon, study, dataset,
fit) a child process is killed (SIGKILL: no clean-up runs) after the first file is in place, between a temporary
and its rename, and while the manifest is being written. Then: the output is the old one, absent, or marked
incomplete; the rerun (or ``--resume``) in this process finishes; every data file equals, byte for byte, that of an
uninterrupted run with the same seed and every manifest fact but timings and the command line is the same; no
temporary, lock or partial file is left. The uninterrupted runs and the reruns run in this process (Mitsuba
imported once); only the killed runs are child processes. Deterministic: no sleeps, no races.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fault_helpers import (ROOT, assert_no_leftovers, assert_same_output, killed_cli, killed_python, run_cli,
                           strip_volatile, tree)
from transient_core import stack
from transient_core.lock import output_lock

NLOS = ROOT / "scenes" / "nlos_point_targets.xml"
NLOS_D = ["-D", "width=4", "-D", "height=4", "-D", "spots_x=3", "-D", "spots_y=2", "-D", "spot_spacing_m=0.05",
          "-D", "n_bins=32", "-D", "bin_width_ps=128", "--spp", "16", "--seed", "3"]
NOISE_D = ["-D", "width=4", "-D", "height=4", "-D", "spots_x=2", "-D", "spots_y=1", "-D", "n_bins=96",
           "-D", "bin_width_ps=40", "-D", "t0_ps=11000", "-D", "include_wall_return=false", "--spp", "16",
           "--seed", "7", "--noise-target", "0.5", "--pulses", "50", "--max-spp", "16384"]
CAMERA = ROOT / "scenes" / "cornell_box.xml"
CAMERA_D = ["-D", "width=4", "-D", "height=4", "-D", "n_bins=20", "--spp", "2", "--seed", "1"]
FOG = ROOT / "scenes" / "fog_nlos.xml"
FOG_D = ["-D", "width=4", "-D", "height=4", "-D", "spots_x=2", "-D", "spots_y=1", "-D", "n_bins=64",
         "-D", "bin_width_ps=64", "--spp", "8", "--seed", "2"]

QUAD = ROOT / "scenes" / "nlos_letter.xml"  # the deterministic estimator (error_bound/ beside the spots)
QUAD_D = ["-D", "width=3", "-D", "height=3", "-D", "spots_x=3", "-D", "spots_y=1", "-D", "n_bins=64",
          "-D", "bin_width_ps=64", "-D", "t0_ps=10000", "-D", "estimator=quadrature", "-D", "element_size_m=0.04",
          "-D", "patch_cells=2"]

RENDERS = {"nlos": (NLOS, NLOS_D), "noise_target": (NLOS, NOISE_D), "camera": (CAMERA, CAMERA_D),
           "fog": (FOG, FOG_D), "quadrature": (QUAD, QUAD_D)}
#: (render, fault point): after the first file, between a temporary and its rename, during the manifest
RENDER_FAULTS = [
    ("nlos", "after_rename@cap/spot_*.exr:1"),
    ("nlos", "before_rename@variance/spot_*.exr:3"),
    ("nlos", "before_rename@cap/spot_*.exr:4"),
    ("nlos", "before_rename@manifest.json:2"),  # the final manifest (the first one says 'incomplete')
    ("noise_target", "after_rename@cap/spot_*.exr:1"),  # a spot in place, its group's checkpoint not yet removed
    ("noise_target", "before_rename@group_*.npz:2"),
    ("noise_target", "before_rename@manifest.json:2"),
    ("camera", "before_rename@cap/spot_*.exr:1"),
    ("camera", "before_rename@preview.png:1"),
    ("fog", "after_rename@variance/spot_*.exr:1"),
    ("quadrature", "after_rename@cap/spot_*.exr:1"),
    ("quadrature", "before_rename@error_bound/spot_*.exr:2"),
]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Uninterrupted renders, made once, in this process."""
    base = tmp_path_factory.mktemp("fault_ref")
    out = {}
    for name, (scene, args) in RENDERS.items():
        r = run_cli("render", scene, "-o", base / name, *args)
        assert r.code == 0, r.err
        out[name] = base / name
    return out


def _incomplete_or_absent(d: Path) -> None:
    if not d.exists() or not stack.manifest_path(d).exists():
        return
    m = stack.read_manifest(d)
    assert m["status"] == "incomplete"
    with pytest.raises(stack.StackError):
        stack.read_stack(d)


@pytest.mark.parametrize("render, fault", RENDER_FAULTS, ids=[f"{r}-{f}" for r, f in RENDER_FAULTS])
def test_render_killed_then_resumed_equals_uninterrupted(tmp_path, reference, render, fault):
    scene, args = RENDERS[render]
    out = tmp_path / "cap"
    killed_cli("render", scene, "-o", out, *args, fault=fault)
    _incomplete_or_absent(out)
    r = run_cli("render", scene, "-o", out, *args, "--resume")
    assert r.code == 0, r.err
    n = assert_same_output(reference[render], out)
    assert n >= 3
    assert_no_leftovers(tmp_path)


# --- detect, recon, study, dataset, fit ------------------------------------------------------------------------

DETECT = ["--pulses", "2000", "--seed", "4"]
#: (fault, whether an earlier output is there to be replaced with --overwrite)
DETECT_FAULTS = [
    ("after_rename@spot_*.exr:1", False),  # the first counts file written (in the temporary directory)
    ("before_rename@counts:1", False),  # the finished temporary directory, not yet renamed
    ("after_rename@counts/spot_*.exr:1", True),  # replacing an earlier output: the first spot moved in
    ("before_rename@counts/manifest.json:1", True),  # ... every spot moved in, the manifest not yet
]


@pytest.mark.parametrize("fault, again", DETECT_FAULTS, ids=[f for f, _ in DETECT_FAULTS])
def test_detect_killed_then_rerun_equals_uninterrupted(tmp_path, reference, fault, again):
    ref = tmp_path / "ref" / "counts"
    assert run_cli("detect", reference["nlos"], "-o", ref, *DETECT).code == 0
    out = tmp_path / "run" / "counts"
    extra = []
    if again:  # an earlier detection with another seed sits in OUT
        assert run_cli("detect", reference["nlos"], "-o", out, "--pulses", "2000", "--seed", "5").code == 0
        extra = ["--overwrite"]
    killed_cli("detect", reference["nlos"], "-o", out, *DETECT, *extra, fault=fault)
    if again:
        assert not stack.manifest_path(out).exists()  # not a capture until the new manifest lands
    else:
        assert not out.exists()
    r = run_cli("detect", reference["nlos"], "-o", out, *DETECT, *extra)
    assert r.code == 0, r.err
    assert_same_output(ref, out)
    assert_no_leftovers(tmp_path)


RECON = ["--voxels", "8", "--method", "bp", "--seed", "1"]


@pytest.fixture(scope="module")
def recon_ref(reference, tmp_path_factory):
    ref = tmp_path_factory.mktemp("recon_ref") / "rec"
    assert run_cli("recon", reference["nlos"], "-o", ref, *RECON).code == 0
    return ref


@pytest.mark.parametrize("fault, again", [("before_rename@rec:1", False), ("replace_dir@rec:1", True)])
def test_recon_killed_leaves_the_old_output_or_none_and_rerun_equals_uninterrupted(tmp_path, reference, recon_ref,
                                                                                   fault, again):
    ref = recon_ref
    out = tmp_path / "run" / "rec"
    extra = []
    if again:
        assert run_cli("recon", reference["nlos"], "-o", out, *RECON, "--seed", "2").code == 0
        old = tree(out)
        extra = ["--overwrite"]
    killed_cli("recon", reference["nlos"], "-o", out, *RECON, *extra, fault=fault)
    if fault.startswith("replace_dir"):  # killed between moving the old output aside and putting the new one
        assert not out.exists()  # in place: OUT is absent until the next run that takes its lock puts it back
        with output_lock(out):
            assert tree(out) == old
    else:
        assert not out.exists()
    r = run_cli("recon", reference["nlos"], "-o", out, *RECON, *extra)
    assert r.code == 0, r.err
    assert_same_output(ref, out)
    assert_no_leftovers(tmp_path)


STUDY = ["study", "array-size", "--arrays", "2", "-D", "spp=16", "--exposure-ms", "1", "--voxels", "8", "--quick"]


@pytest.mark.parametrize("fault", ["before_rename@study:1"])
def test_study_killed_then_rerun_equals_uninterrupted(tmp_path, fault):
    ref = tmp_path / "ref" / "study"
    r = run_cli(*STUDY, "-o", ref)
    assert r.code == 0, r.err
    out = tmp_path / "run" / "study"
    killed_cli(*STUDY, "-o", out, fault=fault)
    assert not out.exists()
    r = run_cli(*STUDY, "-o", out)
    assert r.code == 0, r.err
    # timings.csv, summary.md and array_size.png (error *and time* against array size) show timings
    assert_same_output(ref, out, text_skip=[r"timings\.csv", r"summary\.md", r"array_size\.png",
                                             r"timings\.json"],
                       csv_volatile=("time_s",))
    assert_no_leftovers(tmp_path)


DATASET_SPEC = """\
scene: nlos_point_targets
seed: 1
spp: 8
defines: {width: 4, height: 4, spots_x: 1, spots_y: 1, n_bins: 32, bin_width_ps: 128}
grid:
  max_depth: [3, 4]
"""


def test_dataset_killed_while_writing_its_index_then_rerun_equals_uninterrupted(tmp_path):
    spec = tmp_path / "spec.yaml"
    spec.write_text(DATASET_SPEC)
    ref, out = tmp_path / "ref", tmp_path / "run"
    r = run_cli("dataset", spec, "-o", ref, "--workers", "1")
    assert r.code == 0, r.err
    killed_cli("dataset", spec, "-o", out, "--workers", "1", fault="before_rename@index.csv:1")
    r = run_cli("dataset", spec, "-o", out, "--workers", "1")  # a rerun resumes
    assert r.code == 0, r.err
    assert_same_output(ref, out, text_skip=[r".*\.log", r"\.dataset\.lock"])
    # (OUT/.dataset.lock is the dataset runner's flock(2) file: its presence holds nothing, the kernel's lock does)
    assert_no_leftovers(tmp_path, allow=(".dataset.lock",))


FIT_CODE = """
import sys
from transient_mi.fit import FitSettings, fit_capture
fit_capture(sys.argv[1], sys.argv[2], model="patches", n_patches=1, patch_side_m=0.3, bin_width_ps=128.0,
            settings=FitSettings(iterations=3, checkpoint_every=1, spp=4, spp_residual=4, seed=1,
                                 estimator="monte_carlo"),
            resume=len(sys.argv) > 3, progress=False, log=lambda *a: None)
"""
#: The defaults' fit (the quadrature and Gauss-Newton: deterministic), four iterations.
FIT_GN_CODE = """
import sys
from transient_mi.fit import FitSettings, fit_capture
fit_capture(sys.argv[1], sys.argv[2], model="patches", n_patches=1, patch_side_m=0.3, bin_width_ps=128.0,
            settings=FitSettings(iterations=4, checkpoint_every=1, sigma_start_ps=400.0),
            resume=len(sys.argv) > 3, progress=False, log=lambda *a: None)
"""


def _fit_counts(tmp_path: Path) -> Path:
    ideal, counts = tmp_path / "ideal", tmp_path / "counts"
    r = run_cli("render", ROOT / "scenes" / "nlos_tilted_plane.xml", "-o", ideal, "--spp", "16", "-D", "width=4",
                "-D", "estimator=monte_carlo",
                "-D", "height=4", "-D", "spots_x=1", "-D", "spots_y=1", "-D", "n_bins=48", "-D", "bin_width_ps=128")
    assert r.code == 0, r.err
    assert run_cli("detect", ideal, "-o", counts, *DETECT).code == 0
    return counts


def test_gauss_newton_fit_killed_after_its_checkpoint_resumes_to_the_same_bytes(tmp_path):
    """The defaults' fit killed after its second checkpoint and resumed: the parameters, the objectives and
    ``fitted.ply`` of an uninterrupted run, byte for byte (each iteration starts from the checkpointed parameters
    and damping only)."""
    import subprocess
    import sys

    counts = _fit_counts(tmp_path)
    ref, out = tmp_path / "ref", tmp_path / "fit"
    r = subprocess.run([sys.executable, "-c", FIT_GN_CODE, str(counts), str(ref)], capture_output=True, text=True,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr
    killed_python(FIT_GN_CODE, counts, out, fault="after_rename@checkpoint.json:2")
    assert json.loads((out / "checkpoint.json").read_text())["iteration"] == 2
    assert not (out / "fit.json").exists()
    r = subprocess.run([sys.executable, "-c", FIT_GN_CODE, str(counts), str(out), "resume"], capture_output=True,
                       text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    a, b = (json.loads((d / "fit.json").read_text()) for d in (ref, out))
    assert a["optimizer"]["used"] == "gauss_newton"
    assert a["parameters"] == b["parameters"] and a["history"]["objective"] == b["history"]["objective"]
    assert a["poisson_nll"] == b["poisson_nll"]
    assert (ref / "fitted.ply").read_bytes() == (out / "fitted.ply").read_bytes()
    assert_no_leftovers(tmp_path)


def test_fit_killed_after_its_checkpoint_resumes_to_the_end(tmp_path):
    counts = _fit_counts(tmp_path)
    out = tmp_path / "fit"
    killed_python(FIT_CODE, counts, out, fault="after_rename@checkpoint.json:2")
    ckpt = json.loads((out / "checkpoint.json").read_text())
    assert ckpt["iteration"] == 2
    assert not (out / "fit.json").exists()  # no result yet: the fit is incomplete
    from transient_mi.fit import FitSettings, fit_capture

    res = fit_capture(counts, out, model="patches", n_patches=1, patch_side_m=0.3, bin_width_ps=128.0,
                      settings=FitSettings(iterations=3, checkpoint_every=1, spp=4, spp_residual=4, seed=1,
                                           estimator="monte_carlo"),
                      resume=True, progress=False, log=lambda *a: None)
    assert res["status"] == "complete" and len(res["history"]["objective"]) == 3
    assert json.loads((out / "fit.json").read_text())["status"] == "complete"
    assert json.loads((out / "checkpoint.json").read_text())["iteration"] == 3
    # (Monte Carlo and Adam: not compared with an uninterrupted fit byte for byte, the Monte Carlo gradient's reverse
    # mode is not bit-reproducible between runs, docs/fit.md; the Gauss-Newton test above is)
    assert_no_leftovers(tmp_path)


#: The free-mesh fit (``--model mesh``: the quadrature throughout, its reverse pass in a fixed order), small: two
#: alignment iterations, three carving iterations on the start grown by one ring, four vertex iterations in two
#: stages, a checkpoint after each.
FIT_MESH_CODE = """
import sys
from transient_mi.fit import FitSettings, fit_capture
from transient_mi.fit.mesh_fit import MeshSettings
fit_capture(sys.argv[1], sys.argv[2], model="mesh", bin_width_ps=32.0,
            settings=FitSettings(iterations=4, checkpoint_every=1, sigma_start_ps=120.0, element_size_m=0.06),
            mesh=MeshSettings(align=2, carve=3, grow=1, stages=2),
            resume=len(sys.argv) > 3, progress=False, log=lambda *a: None)
"""
#: Where the mesh fit is killed: its carving written (the vertex stage not begun), its second checkpoint written.
FIT_MESH_FAULTS = ["after_rename@carve.json:1", "after_rename@checkpoint.json:2"]


@pytest.fixture(scope="module")
def mesh_fit_reference(tmp_path_factory):
    """The tilted plane rendered by the quadrature (4 x 4 pixels of 8 cm, one spot, 200 bins of 32 ps), detected,
    and the uninterrupted mesh fit of it (:data:`FIT_MESH_CODE`, in a child process as the killed ones):
    ``(counts, fit directory)``."""
    import subprocess
    import sys

    base = tmp_path_factory.mktemp("mesh_fit_ref")
    ideal, counts, ref = base / "ideal", base / "counts", base / "ref"
    r = run_cli("render", ROOT / "scenes" / "nlos_tilted_plane.xml", "-o", ideal, "-D", "estimator=quadrature",
                "-D", "element_size_m=0.04", "-D", "patch_cells=2", "-D", "width=4", "-D", "height=4",
                "-D", "pixel_footprint_m=0.08", "-D", "spots_x=1", "-D", "spots_y=1", "-D", "n_bins=200",
                "-D", "bin_width_ps=32", "-D", "t0_ps=10500")
    assert r.code == 0, r.err
    assert run_cli("detect", ideal, "-o", counts, *DETECT).code == 0
    r = subprocess.run([sys.executable, "-c", FIT_MESH_CODE, str(counts), str(ref)], capture_output=True, text=True,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr
    return counts, ref


@pytest.mark.parametrize("fault", FIT_MESH_FAULTS)
def test_mesh_fit_killed_then_resumed_equals_uninterrupted(tmp_path, mesh_fit_reference, fault):
    """The free-mesh fit killed after its carving or after its second checkpoint and resumed: every file of an
    uninterrupted fit, byte for byte (the meshes, figures, ``fitted.ply``), JSON fact for fact but timings. Before
    the quadrature's reverse pass summed in a fixed order (2026-12-07) the carving's reflectances differed from run
    to run, and at both kill points the resumed fit's ``fit.json`` differed from the uninterrupted one's."""
    import subprocess
    import sys

    counts, ref = mesh_fit_reference
    out = tmp_path / "fit"
    killed_python(FIT_MESH_CODE, counts, out, fault=fault)
    assert not (out / "fit.json").exists()
    r = subprocess.run([sys.executable, "-c", FIT_MESH_CODE, str(counts), str(out), "resume"], capture_output=True,
                       text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert assert_same_output(ref, out, text_skip=[r"carve\.json", r"checkpoint\.json"]) >= 10
    for name in ("carve.json", "checkpoint.json"):  # (their history rows hold the seconds third)
        a, b = (strip_volatile(json.loads((d / name).read_text())) for d in (ref, out))
        for c in (a, b):
            c["history"] = [row[:2] + row[3:] for row in c["history"]]
        assert a == b, name
    assert_no_leftovers(tmp_path)


@pytest.mark.parametrize("command", ["video", "export"])
def test_a_file_output_killed_before_its_rename_is_absent_and_the_rerun_leaves_no_temporary(tmp_path, reference,
                                                                                           command):
    name = {"video": "slices.gif", "export": "capture.h5"}[command]
    args = {"video": ["video", reference["nlos"], "-o"], "export": ["export", reference["nlos"]]}[command]
    tail = {"video": [], "export": ["--to", "ytal"]}[command]
    ref = tmp_path / "ref" / name
    ref.parent.mkdir()
    assert run_cli(*args, ref, *tail).code == 0
    out = tmp_path / "run" / name
    out.parent.mkdir()
    killed_cli(*args, out, *tail, fault=f"before_rename@{name}:1")
    assert not out.exists()
    r = run_cli(*args, out, *tail)
    assert r.code == 0, r.err
    if command == "video":
        assert out.read_bytes() == ref.read_bytes()
    else:  # HDF5 files hold their creation time: compare the data
        import h5py

        with h5py.File(ref) as a, h5py.File(out) as b:
            names = []
            a.visit(names.append)
            for n in names:
                if isinstance(a[n], h5py.Dataset):
                    va, vb = np.asarray(a[n][()]), np.asarray(b[n][()])
                    if va.dtype.kind in "fiucb":
                        assert va.tobytes() == vb.tobytes(), n
                    else:  # strings
                        assert va.tolist() == vb.tolist(), n
    assert_no_leftovers(tmp_path)


#: (what was killed, where) for the test summary (tests/conftest.py's pytest_terminal_summary)
KILL_POINTS = ([(f"render {r}", f) for r, f in RENDER_FAULTS] + [("detect", f) for f, _ in DETECT_FAULTS]
               + [("recon", "before_rename@rec:1"), ("recon --overwrite", "replace_dir@rec:1"), ("study", "before_rename@study:1"),
                  ("dataset", "before_rename@index.csv:1"), ("fit", "after_rename@checkpoint.json:2"),
                  *[("fit --model mesh", f) for f in FIT_MESH_FAULTS],
                  ("video", "before_rename@slices.gif:1"), ("export", "before_rename@capture.h5:1")])
