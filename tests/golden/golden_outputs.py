"""Hashes of what rendering, detection and reconstruction produce on the embedded scenes.

``python tests/golden/golden_outputs.py --write`` records them in ``tests/data/golden_hashes.json`` (for this
machine's CPU class);
``tests/test_golden_outputs.py`` recomputes them and compares. The hashes are of the arrays (the
data bytes), not of the files, whose headers hold versions and render times. They were first taken
on main at ae183f4, before the package layout changed (issue 12): the same seed must give the same
bytes after a refactor. One case was re-taken after that change, for a reason: ``cornell_camera`` first
had a time window that held no light (an all-zero hash, blind to camera changes); its window now holds
the light, and it was recorded after cameras began to honour the film's reconstruction filter (Mitsuba's
default ``gaussian``, issue 12), which changes camera bytes by design -- the box-filter bytes of the old
renderer are pinned separately in ``tests/test_sampler_rfilter.py``. The stream layout depends on the backend only (see
``transient_mi/integrators/_lanes.py``), but the bytes also depend on the instructions LLVM selects for the
host CPU: the same code gives other bytes on an AVX-512 machine than on an AVX2-only one (the first hashes
were taken on an AVX-512 Xeon; an AVX2 AMD EPYC differs in three of the five cases, e.g. approximate
reciprocal square roots differ between the two instruction sets). So the record holds one set of hashes
per CPU class (:func:`cpu_class`); the ``avx2`` set was taken on 13eed65 (the commit before the
estimator work) and checked equal on the commit that recorded it.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
HASHES = HERE.parent / "data" / "golden_hashes.json"
sys.path.insert(0, str(HERE.parent))
from cpu_helpers import cpu_class  # noqa: E402,F401  (tests/cpu_helpers.py; re-exported for the test)

#: (name, scene file, -D defines, spp, seed): small but each path through the renderer. The NLOS scenes whose
#: default estimator is the quadrature are pinned with ``estimator=monte_carlo``: these are Monte Carlo bytes.
CASES = [
    ("cornell_camera", "cornell_box.xml", {"width": 12, "height": 10, "n_bins": 48, "max_depth": 4, "t0_ps": 13000,
                                           "bin_width_ps": 100}, 8, 3),
    ("letter_array", "nlos_letter.xml", {"width": 6, "height": 5, "spots_x": 2, "spots_y": 1, "n_bins": 160,
                                            "estimator": "monte_carlo"}, 8, 5),
    ("points_confocal", "nlos_point_targets.xml", {"width": 5, "height": 4, "capture": "confocal", "n_bins": 160}, 8, 7),
    ("plane_array", "nlos_tilted_plane.xml", {"width": 4, "height": 4, "spots_x": 1, "spots_y": 1, "n_bins": 256,
                                                "estimator": "monte_carlo"}, 8, 9),
    ("mannequin_array", "paper_mannequin.xml", {"array": 4, "spots": 1, "n_bins": 1500, "bin_width_ps": 8,
                                                  "estimator": "monte_carlo"}, 16, 11),
]


def _sha(a) -> str:
    import numpy as np

    a = np.ascontiguousarray(a)
    return hashlib.sha256(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes()).hexdigest()[:24]


def _stack_hash(d: Path) -> dict:
    import numpy as np

    from transient_core.stack import has_variance, read_stack, read_variance

    m, data = read_stack(d)
    out = {"data": _sha(data)}
    if has_variance(m):
        var = [read_variance(d, j, m) for j in range(data.shape[0])]
        out["variance"] = _sha(np.stack([v for v, _ in var]))
        out["total_variance"] = _sha(np.stack([t for _, t in var]))
    return out


def compute(work: Path) -> dict:
    import transient_mi  # noqa: F401  (LLVM set-up and plug-ins first)
    from transient_mi.render_capture import render
    from transient_mi.scenes import scene_path
    from spad_detector import detect_stack
    from recon.pipeline import run

    hashes = {}
    for name, scene, defines, spp, seed in CASES:
        cap = work / name
        render(scene_path(scene), cap, defines={k: str(v) for k, v in defines.items()}, spp=spp, seed=seed,
               progress=False)
        entry = {"ideal": _stack_hash(cap)}
        if scene != "cornell_box.xml":
            det = work / f"{name}_counts"
            detect_stack(cap, det, pulses=5_000_000, seed=seed, progress=False, warn=False)
            entry["counts"] = _stack_hash(det)
            import numpy as np

            rec, _, out = run(det, work / f"{name}_recon", "bp", voxels=16, filter="none", plots=False, seed=seed)
            with np.load(out / "volume.npz") as z:
                entry["volume"] = _sha(z["volume"])
        hashes[name] = entry
    return hashes


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    with tempfile.TemporaryDirectory() as t:
        h = compute(Path(t))
    if "--write" in argv:  # this CPU class's entry only
        rec = json.loads(HASHES.read_text()) if HASHES.exists() else {}
        rec[cpu_class()] = h
        HASHES.write_text(json.dumps(rec, indent=2, sort_keys=True) + "\n")
    print(json.dumps(h, indent=2, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
