"""The integrator benchmark runs (small) and prints the documented JSON; no timing assertions."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_integrator_small_prints_json():
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_integrator.py"), "--small"],
                       capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    for key in ("path", "transient_path", "throughput_ratio", "goal_ratio", "meets_goal", "film_memory_mb"):
        assert key in out
    assert out["transient_path"]["paths_per_s"] > 0 and out["path"]["paths_per_s"] > 0
    assert out["transient_path"]["film"] == "32x32x64"
