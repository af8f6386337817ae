"""The studies benchmark runs at a tiny size and prints parseable JSON (no timing assertions)."""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_studies_small_prints_json():
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_studies.py"), "--small"], cwd=ROOT,
                       capture_output=True, text=True, timeout=600, env=dict(os.environ, TRANSIENT_MI_PROGRESS="0"))
    assert r.returncode == 0, r.stderr + r.stdout
    out = json.loads(r.stdout)
    assert out["small"] is True and [c["case"] for c in out["cases"]] == ["photon_small", "array_small"]
    for c in out["cases"]:
        assert c["status"] == "ok", c
        assert c["wall_s"] > 0 and c["peak_rss_mb"] > 0 and c["runs"] >= 1
        assert set(c["step_sums_s"]) >= {"detect_s", "reconstruct_s", "metrics_s", "total_s"}
