"""Same seed, same bytes across refactors: rendering, detection and reconstruction of the embedded scenes
hash to the values recorded before the package layout changed, per CPU class (see tests/golden/golden_outputs.py
for how they were taken, why AVX-512 and AVX2 machines differ, and the one case re-taken on purpose)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def test_outputs_hash_to_the_recorded_values(tmp_path):
    sys.path.insert(0, str(HERE / "golden"))
    try:
        import golden_outputs
    finally:
        sys.path.pop(0)
    recorded = json.loads(golden_outputs.HASHES.read_text())
    cls = golden_outputs.cpu_class()
    assert cls in recorded, (f"no golden hashes recorded for this CPU class ({cls}; recorded: {sorted(recorded)}): "
                             "record them from a commit known to be right with "
                             "`python tests/golden/golden_outputs.py --write`")
    want = recorded[cls]
    got = golden_outputs.compute(tmp_path)
    diff = {name: (want.get(name), got.get(name)) for name in set(want) | set(got) if want.get(name) != got.get(name)}
    assert not diff, f"outputs changed for the same seed: {diff}"
