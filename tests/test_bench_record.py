"""bench/_record.py: the JSON record every benchmark writes, and its peak-memory measurement (deterministic)."""

import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import _record  # noqa: E402


def test_record_has_machine_date_command_versions_and_is_written_atomically(tmp_path):
    rec = _record.record("demo_x", {"value": 1.5}, load_start=[1.0, 1.0, 1.0], note="shared machine",
                         peers={"y-tal": "0.20.0"}, argv=[str(ROOT / "bench" / "bench_demo.py"), "--quick"])
    assert rec["command"] == "python bench/bench_demo.py --quick"
    m = rec["machine"]
    assert m["cores"] >= 1 and m["memory_gib"] > 0 and m["cpu_model"]
    assert m["load_average_1min_start"] == 1.0 and m["load_average_1min_end"] >= 0
    assert rec["versions"]["numpy"] == np.__version__ and rec["versions"]["y-tal"] == "0.20.0"
    assert rec["note"] == "shared machine" and rec["result"] == {"value": 1.5}
    assert rec["date_utc"].endswith("+00:00")
    path = _record.save(rec, tmp_path / "out" / "demo_x.json")
    assert json.loads(path.read_text()) == rec
    assert [p.name for p in path.parent.iterdir()] == ["demo_x.json"]  # no temporary file left


def test_peak_rss_is_this_process_and_can_be_reset():
    _record.reset_peak_rss()
    before = _record.peak_rss_mb()
    a = np.ones(64 * 2 ** 20 // 8)  # 64 MiB touched
    grown = _record.peak_rss_mb()
    del a
    assert grown - before > 50
    if _record.reset_peak_rss():  # kernels that refuse clear_refs leave the peak as it was
        assert _record.peak_rss_mb() < grown - 50
    assert _record.rss_mb() <= _record.peak_rss_mb()


def test_run_measured_reports_the_childs_own_peak(tmp_path):
    # a parent with a large peak must not pass it on to the child (unlike ru_maxrss over fork + exec)
    big = np.ones(256 * 2 ** 20 // 8)
    r = _record.run_measured(["json.tool", "--help"], cwd=tmp_path, log=tmp_path / "log.txt")
    del big
    assert r["returncode"] == 0 and r["wall_s"] > 0
    assert 0 < r["peak_rss_mb"] < 200, r
