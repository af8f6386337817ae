"""The quadrature-vs-mitransient benchmark runs (small sizes) and prints the JSON it documents.

No timing assertions. The one numerical check is deterministic: the quadrature's error against its finer
reference is smaller at the finer element size of the sweep (second-order convergence; no statistics).
"""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_nlos_quadrature_small_prints_json(tmp_path):
    out = tmp_path / "bench.json"
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_nlos_quadrature.py"), "--small",
                        "--mitransient", "auto", "--out", str(out)], capture_output=True, text=True, cwd=ROOT,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    report = json.loads(r.stdout)
    assert report == json.loads(out.read_text())
    assert report["benchmark"] == "nlos_quadrature" and report["small"] is True
    assert [c["name"] for c in report["configs"]] == ["confocal_8x8_64bins", "array_4x4px_4x4spots_64bins"]
    for c in report["configs"]:
        q = c["quadrature"]
        errs = [s["rel_rmse"] for s in q["sweep"]]
        assert len(errs) >= 2 and all(e > 0 for e in errs)
        assert errs[-1] < errs[0]  # finer elements, smaller error
        sel = q["selected"]
        assert sel["rel_rmse"] <= c["target_rel_rmse"] and sel["time_s"] > 0
        assert sel["timed_spots"] == (16 if c["capture"] == "array" else 1)
        x = c["reference_check_monte_carlo"]
        assert x["replicates"] == 16 and x["mc_stated_rel_rms_noise"] > 0
        if report["mitransient"]["available"]:
            m = c["mitransient"]
            assert m["rel_rmse"] > 0 and m["time_s"] > 0
            assert {"scale_ours_over_mitransient", "expected_scale"} <= set(c["mean_agreement"])
        else:
            assert c["mitransient"] is None
