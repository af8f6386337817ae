"""The detector benchmark runs small and prints the documented JSON (no timing assertions)."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_detector_small_prints_json():
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_detector.py"), "--small"], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["small"] is True and out["pixels"] == 16
    for key in ("analytic_gated", "analytic_ungated"):
        assert {"pulses", "cold_s", "warm_s", "counts", "exact", "regimes"} <= set(out[key])
    assert out["analytic_gated"]["exact"] is True
    assert {"pixel_pulses_per_s", "events_per_s", "seconds", "pulses"} <= set(out["exact"])
