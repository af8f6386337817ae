"""The NLOS benchmark runs (small sizes) and prints the JSON it documents; no timing assertions."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_nlos_small_prints_json(tmp_path):
    out = tmp_path / "bench.json"
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_nlos.py"), "--small", "--mitransient", "auto",
                        "--out", str(out)], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    report = json.loads(r.stdout)
    assert report == json.loads(out.read_text())
    assert report["benchmark"] == "nlos" and report["small"] is True
    names = [c["name"] for c in report["configs"]]
    assert names == ["confocal_8x8_64bins", "array_4x4px_4x4spots_64bins"]
    for c in report["configs"]:
        ours = c["ours"]
        assert len(ours["runs"]) >= 2
        for run in ours["runs"]:
            assert run["time_s"] > 0 and run["rel_rmse"] > 0 and run["max_rss_mb"] > 0
        assert set(ours["time_to_rel_rmse_s"]) == {"0.2", "0.1", "0.05"}
        assert {"A", "beta"} <= set(ours["error_model"])
        if report["mitransient"]["available"]:
            assert set(c["speedup_time_to_equal_error"]) == {"0.2", "0.1", "0.05"}
            assert {"scale_ours_over_mitransient", "expected_scale", "rel_rms_residual_of_totals"} <= set(
                c["mean_agreement"])
        else:
            assert c["mitransient"] is None
    arr = report["configs"][1]["ours_pipeline"]
    assert set(arr) == {"2x2_spots", "4x4_spots"}
    assert arr["4x4_spots"]["files"] == 16 and arr["2x2_spots"]["files"] == 4
