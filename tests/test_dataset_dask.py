"""``transient-mi dataset`` on Dask: items and index, a killed worker, resume, reproducibility, --scheduler.

Tiny renders (the Cornell box at 8 x 8 pixels, 2 spp, 50 bins) on 2-process
local clusters: one started by the command itself (``--workers 2``), one
started here and reached with ``--scheduler``.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from transient_core.errors import UserInputError
from transient_core import stack
from transient_mi.dataset import item_status, read_index, run_dataset
from transient_mi.dataset.worker import KILL_ENV

ROOT = Path(__file__).resolve().parents[1]
MESH_SCENE = ROOT / "tests" / "data" / "dataset_mesh_scene.xml"
SPEC = """\
name: test-cbox
scene: cornell_box
seed: 11
spp: 2
repeats: 2
defines: {width: 8, height: 8, n_bins: 50, bin_width_ps: 600}
grid:
  max_depth: [2, 3]
random:
  t0_ps: {uniform: [9000, 11000], round: 1}
"""
N_ITEMS = 4
KILLED_ITEM = 1


def cli(*args, env=None):
    e = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    e.update(env or {})
    return subprocess.run([sys.executable, "-m", "transient_mi", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, env=e, timeout=600)


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    """Relative path -> (inode, mtime_ns) of every file under root."""
    return {p.relative_to(root).as_posix(): (p.stat().st_ino, p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.is_file()}


def data_files(root: Path) -> dict[str, bytes]:
    """The bytes a dataset must reproduce: EXR spot files, meshes, params.json, the index and dataset.json."""
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and (p.suffix in (".exr", ".ply") or p.name in ("params.json", "index.csv", "index.jsonl",
                                                                        "dataset.json")):
            out[p.relative_to(root).as_posix()] = p.read_bytes()
    return out


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("spec") / "spec.yaml"
    p.write_text(SPEC)
    return p


@pytest.fixture(scope="module")
def cluster():
    """A 2-process local Dask cluster started by the test, for --scheduler."""
    from distributed import LocalCluster

    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                     silence_logs=logging.ERROR)
    yield c
    c.close()


@pytest.fixture(scope="module")
def killed_run(spec_file, tmp_path_factory):
    """The CLI on a 2-process local cluster, with the worker of item 1 SIGKILLed in the middle of it, once."""
    base = tmp_path_factory.mktemp("killed")
    out, flag = base / "ds", base / "killed.json"
    r = cli("dataset", spec_file, "-o", out, "--workers", 2, env={KILL_ENV: f"{KILLED_ITEM}:{flag}"})
    return out, flag, r


@pytest.fixture(scope="module")
def scheduler_run(spec_file, cluster, tmp_path_factory):
    """The CLI with --scheduler pointing at the cluster started by the test."""
    out = tmp_path_factory.mktemp("sched") / "ds"
    r = cli("dataset", spec_file, "-o", out, "--scheduler", cluster.scheduler_address)
    assert r.returncode == 0, r.stderr
    return out, r


def test_local_cluster_builds_every_item_and_the_index(killed_run):
    out, _, r = killed_run
    assert r.returncode == 0, r.stderr
    assert f"{N_ITEMS} items (0 already done, {N_ITEMS} built, 0 failed)" in r.stdout
    assert "local cluster of 2 worker processes" in r.stdout
    names = sorted(p.name for p in (out / "items").iterdir())
    assert names == [f"item_{i:06d}" for i in range(N_ITEMS)]  # no temporary directory left
    rows = read_index(out)
    assert [row["item"] for row in rows] == names and [row["index"] for row in rows] == list(range(N_ITEMS))
    assert [row["define.max_depth"] for row in rows] == [2, 3, 2, 3]
    assert [row["repeat"] for row in rows] == [0, 0, 1, 1]
    assert all(9000 <= row["define.t0_ps"] < 11000 for row in rows)
    csv_lines = (out / "index.csv").read_text().splitlines()
    assert len(csv_lines) == N_ITEMS + 1 and csv_lines[0].startswith("item,index,repeat,grid_index,params_sha256")
    for row in rows:
        d = out / row["capture"]
        m, data = stack.read_stack(d)
        assert m["status"] == "complete" and m["kind"] == "ideal" and data.shape == (1, 8, 8, 50)
        assert data.sum() > 0
        assert m["render"]["seed"] == row["render_seed"] and m["render"]["spp"] == 2
        assert m["time"]["t0_ps"] == row["define.t0_ps"]
        rec = json.loads((out / "items" / row["item"] / "params.json").read_text())
        assert rec["params_sha256"] == row["params_sha256"]
        assert rec["defines"]["max_depth"] == str(row["define.max_depth"])
        assert item_status(out / "items" / row["item"], row["params_sha256"]) == "valid"
    ds = json.loads((out / "dataset.json").read_text())
    assert ds["n_items"] == N_ITEMS and ds["spec"]["grid"] == {"define.max_depth": [2, 3]}


def test_killed_worker_item_is_redone_with_no_partial_item(killed_run):
    out, flag, r = killed_run
    assert r.returncode == 0, r.stderr
    state = json.loads(flag.read_text())  # written by the worker just before it SIGKILLed itself
    # it died mid-item: the capture was started (manifest + first spot) but the item was not finished
    assert "capture/spot_00000.exr" in state["files"] and "capture/manifest.json" in state["files"]
    assert "params.json" not in state["files"] and "result.json" not in state["files"]
    assert Path(state["tmp_dir"]).parent == out / "items" and Path(state["tmp_dir"]).name.startswith(".tmp-")
    assert not Path(state["tmp_dir"]).exists()  # the partial attempt is gone
    res = json.loads((out / "items" / f"item_{KILLED_ITEM:06d}" / "result.json").read_text())
    assert res["worker"].split(":")[1] != str(state["pid"])  # redone by another (restarted) worker process
    m = stack.read_manifest(out / "items" / f"item_{KILLED_ITEM:06d}" / "capture")
    assert m["status"] == "complete"
    assert len(read_index(out)) == N_ITEMS  # nothing duplicated
    # the log says which item was redone, by whom, and what the dead attempt left (one line per retried item)
    name = f"item_{KILLED_ITEM:06d}"
    retried = [ln for ln in r.stderr.splitlines() if "redone by worker" in ln]
    assert len(retried) == 1 and retried[0].startswith(f"{name}: redone by worker {res['worker']}"), r.stderr
    assert Path(state["tmp_dir"]).name in retried[0]
    assert "(a worker died in it;" in retried[0] and str(out / "cluster.log") in retried[0]
    assert f"1 item(s) redone after a worker died ({name})" in r.stdout
    # the nanny's own word on the death is kept (the console shows errors only)
    log = (out / "cluster.log").read_text()
    assert f"Worker process {state['pid']} was killed by signal 9" in log, log


def test_attempt_alive_tells_a_running_worker_from_a_dead_one(tmp_path):
    import os
    import socket
    import subprocess
    import sys

    from transient_mi.dataset.worker import attempt_alive

    host = socket.gethostname()
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        assert attempt_alive(f".tmp-item_000003-{host}-{child.pid}-0a1b2c3d")
        assert not attempt_alive(f".tmp-item_000003-other-host-{child.pid}-0a1b2c3d")  # cannot be asked
        assert not attempt_alive(f".tmp-item_000003-{host}-{os.getpid()}-0a1b2c3d")  # this process
    finally:
        child.kill()
        child.wait()
    assert not attempt_alive(f".tmp-item_000003-{host}-{child.pid}-0a1b2c3d")  # dead (and reaped)
    assert not attempt_alive(".tmp-item_000003-garbage")


def test_scheduler_address_runs_on_an_existing_cluster(scheduler_run, cluster):
    out, r = scheduler_run
    assert f"{N_ITEMS} items (0 already done, {N_ITEMS} built, 0 failed)" in r.stdout
    assert f"on scheduler {cluster.scheduler_address}" in r.stdout
    workers = {json.loads((out / "items" / f"item_{i:06d}" / "result.json").read_text())["worker"]
               for i in range(N_ITEMS)}
    pids = {w.split(":")[1] for w in workers}
    assert pids <= set(map(str, _cluster_pids(cluster))) and str(os.getpid()) not in pids


def _cluster_pids(cluster):
    from distributed import Client

    with Client(cluster) as c:
        return set(c.run(os.getpid).values())


def test_same_spec_and_seed_give_the_same_bytes(killed_run, scheduler_run):
    a, _, r = killed_run
    assert r.returncode == 0, r.stderr
    b, _ = scheduler_run
    fa, fb = data_files(a), data_files(b)
    # one spot file per item (camera renders record no variance by default, docs/noise.md)
    assert sorted(fa) == sorted(fb) and len([k for k in fa if k.endswith(".exr")]) == N_ITEMS
    for k in fa:
        assert fa[k] == fb[k], k


def test_rerun_skips_finished_items(killed_run):
    out, _, r = killed_run
    assert r.returncode == 0, r.stderr
    before = snapshot(out / "items")
    index_before = (out / "index.csv").read_bytes()
    report = run_dataset(_spec_path(out), out)
    assert (report.built, report.existed, report.failed) == (0, N_ITEMS, [])
    assert report.cluster == ""  # nothing to do: no cluster was even started
    assert snapshot(out / "items") == before  # same inodes, same mtimes: nothing rewritten
    assert (out / "index.csv").read_bytes() == index_before


def _spec_path(out: Path) -> Path:
    return Path(json.loads((out / "dataset.json").read_text())["spec_file"])


def test_resume_redoes_missing_and_damaged_items_and_cleans_leftovers(scheduler_run, killed_run, cluster):
    out, _ = scheduler_run
    ref, _, _ = killed_run
    items = out / "items"
    untouched = snapshot(items / "item_000000")
    shutil.rmtree(items / "item_000002")  # as if never finished
    (items / "item_000003" / "capture" / "spot_00000.exr").unlink()  # damaged after the fact
    leftover = items / ".tmp-item_000002-host-123-dead"  # an interrupted attempt
    (leftover / "capture").mkdir(parents=True)
    (leftover / "capture" / "spot_00000.exr").write_bytes(b"partial")
    assert item_status(items / "item_000003") == "damaged"
    report = run_dataset(_spec_path(out), out, scheduler=cluster.scheduler_address)
    assert (report.built, report.existed, report.redone_damaged) == (2, 2, 1)
    assert not leftover.exists() and not [p for p in items.iterdir() if p.name.startswith(".tmp-")]
    assert snapshot(items / "item_000000") == untouched
    assert data_files(out) == data_files(ref)
    assert len(read_index(out)) == N_ITEMS


def test_items_from_other_parameters_stop_the_run_before_work(killed_run, tmp_path):
    out, _, r = killed_run
    assert r.returncode == 0, r.stderr
    before = snapshot(out)
    other = tmp_path / "other.yaml"
    other.write_text(SPEC.replace("seed: 11", "seed: 12"))
    with pytest.raises(UserInputError, match=r"4 existing item\(s\) were made from other parameters"):
        run_dataset(other, out)
    fewer = tmp_path / "fewer.yaml"
    fewer.write_text(SPEC.replace("repeats: 2", "repeats: 1"))
    with pytest.raises(UserInputError, match=r"holds 2 item\(s\) that this spec does not have"):
        run_dataset(fewer, out)
    assert snapshot(out) == before


def test_a_second_run_on_the_same_directory_is_refused(killed_run):
    out, _, r = killed_run
    assert r.returncode == 0, r.stderr
    fd = os.open(out / ".dataset.lock", os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(UserInputError, match="another transient-mi dataset run is writing this directory"):
            run_dataset(_spec_path(out), out)
    finally:
        os.close(fd)


def test_mannequin_items_carry_their_mesh_and_can_be_redone(cluster, tmp_path):
    from transient_mi.scenes.mannequin import mannequin_ply_bytes

    spec = tmp_path / "mq.yaml"
    spec.write_text(f"""\
scene: {MESH_SCENE}
seed: 3
spp: 2
object: {{kind: mannequin, detail: 8}}
grid:
  object.pose: [arms_down, t_pose]
random:
  object.rotation_deg: {{uniform: [-40, 40], round: 1}}
  object.position_z: {{uniform: [0.4, 0.6], round: 3}}
""")
    out = tmp_path / "mq"
    report = run_dataset(spec, out, scheduler=cluster.scheduler_address)
    assert report.built == 2
    rows = read_index(out)
    assert [row["object.pose"] for row in rows] == ["arms_down", "t_pose"]
    meshes = []
    for row in rows:
        rec = json.loads((out / "items" / row["item"] / "params.json").read_text())
        p = rec["object"]["params"]
        assert p["rotation_deg"] == row["object.rotation_deg"] and p["position"][2] == row["object.position_z"]
        mesh = (out / row["mesh"]).read_bytes()
        kw = dict(p, position=tuple(p["position"]))
        assert mesh == mannequin_ply_bytes(**kw)  # the ground truth is exactly the generator's output
        meshes.append(mesh)
        m, data = stack.read_stack(out / row["capture"])
        assert m["render"]["defines"]["mesh"] == "mesh.ply" and data.sum() > 0
    assert meshes[0] != meshes[1]
    # params.json holds everything needed to redo the item: its commands give the same bytes
    item = out / "items" / rows[1]["item"]
    redo = tmp_path / "redo"
    redo.mkdir()
    rec = json.loads((item / "params.json").read_text())
    for cmd in rec["commands"]:
        assert cmd.startswith("transient-mi ")
        r = subprocess.run(f"{sys.executable} -m transient_mi {cmd[len('transient-mi '):]}", shell=True, cwd=redo,
                           capture_output=True, text=True, timeout=600,
                           env=dict(os.environ, TRANSIENT_MI_PROGRESS="0", PYTHONPATH=str(ROOT)))
        assert r.returncode == 0, r.stderr
    assert (redo / "mesh.ply").read_bytes() == (item / "mesh.ply").read_bytes()
    assert (redo / "capture" / "spot_00000.exr").read_bytes() == (item / "capture" / "spot_00000.exr").read_bytes()
    np.testing.assert_array_equal(stack.read_stack(redo / "capture")[1], stack.read_stack(item / "capture")[1])
