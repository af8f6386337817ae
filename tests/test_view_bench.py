"""The viewer benchmark runs at a tiny size and writes parseable JSON (no timing assertions: timing
belongs in the benchmark, not in tests)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_bench_view_small_writes_json(tmp_path):
    pytest.importorskip("playwright", reason="Playwright is not installed (pip install 'transient-mi[test,view]')")
    if not os.path.exists("/usr/bin/chromium"):
        pytest.skip("no Chromium at /usr/bin/chromium (apt-get install chromium; .ci/run installs it)")
    out = tmp_path / "view.json"
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_view.py"), "--repeats", "1", "--pixels", "8",
                        "--bins", "64", "--voxels", "16", "--out", str(out)], cwd=ROOT, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    rec = json.loads(out.read_text())  # the record layout of bench/_record.py
    assert json.loads(r.stdout) == rec
    doc = rec["result"]
    assert rec["command"].startswith("python bench/bench_view.py --repeats 1") and doc["repeats"] == 1
    assert set(doc["cases"]) == {"first_page", "detector_update", "recon_update"}
    for case in doc["cases"].values():
        assert len(case["times_s"]) == 1 and case["times_s"][0] > 0 and isinstance(case["goal_met"], bool)
    assert "16x16x16 voxels" in doc["cases"]["recon_update"]["last_status"]
    assert len(doc["cases"]["detector_update"]["server_cpu_ms"]) == 1
