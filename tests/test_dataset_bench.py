"""The dataset benchmark script runs at a tiny size and prints its JSON (no timing assertions)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_dataset_tiny():
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_dataset.py"), "--tiny", "--repeats", "1",
                        "--workers", "1"], capture_output=True, text=True, cwd=ROOT, timeout=600,
                       env=dict(os.environ, TRANSIENT_MI_PROGRESS="0"))
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    (run,) = out["runs"]
    assert out["benchmark"] == "dataset" and out["tiny"] and run["items"] == 5 and run["workers"] == 1
    assert run["items_per_hour"] > 0 and run["items_per_worker_process"] == [5]
