"""The methods benchmark runs at a tiny size and writes parseable JSON with every repeat (no timing assertions)."""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_recon_methods_small_writes_json(tmp_path):
    out = tmp_path / "m.json"
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_recon_methods.py"), "--small", "--repeat", "2",
                        "--methods", "bp,midpoint-fk", "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
                       timeout=600, env=dict(os.environ, TRANSIENT_MI_PROGRESS="0"))
    assert r.returncode == 0, r.stderr
    rec = json.loads(out.read_text())  # the record layout of bench/_record.py
    doc = rec["result"]
    assert doc["small"] is True and rec["command"].startswith("python bench/bench_recon_methods.py")
    assert rec["machine"]["cpu_count"] >= 1 and rec["date_utc"].endswith("Z") and rec["name"] == "m"
    assert [c["method"] for c in doc["results"]] == ["bp", "midpoint-fk"]
    for c in doc["results"]:
        assert c["status"] == "ok" and len(c["times_s"]) == 2 and c["best_s"] == min(c["times_s"])
        assert c["peak_rss_mb"] > 0 and c["shape_zyx"] == [16, 16, 16]
