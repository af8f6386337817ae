"""The recon benchmark runs at a tiny size and prints parseable JSON (no timing assertions)."""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_recon_small_prints_json():
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_recon.py"), "--small"], cwd=ROOT,
                       capture_output=True, text=True, timeout=600, env=dict(os.environ, TRANSIENT_MI_PROGRESS="0"))
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["small"] is True
    names = [c["case"] for c in out["cases"]]
    assert names == ["bp64", "bp128", "phasor64", "lct64", "fk64", "bp64_confocal"]
    for c in out["cases"]:
        o = c["ours"]
        assert o["status"] == "ok", o
        assert o["time_s"] >= 0 and o["peak_rss_mb"] > 0 and len(o["shape_zyx"]) == 3
