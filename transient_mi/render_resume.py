"""What an interrupted render leaves in its capture directory, and how ``--resume`` reads it back.

Each spot's facts (dropped light, the noise-target result) are written to ``OUT/.partial/spot_NNNNN.json``
before its variance and spot files (:mod:`transient_mi.render_capture` writes them in that order), so a spot
file under its final name implies both; ``--resume`` keeps a spot only when all three are there, and sums the
capture's figures from the facts of every spot, as an uninterrupted render does. The directory
``OUT/.partial/`` is removed once the complete manifest is written.
"""

from __future__ import annotations

import json
from pathlib import Path

from transient_core import stack
from transient_core.atomic import atomic_file

from .noise_target import PARTIAL_DIR


def facts_path(d: Path, j: int) -> Path:
    return d / PARTIAL_DIR / f"spot_{j:05d}.json"


def write_spot_facts(d: Path, j: int, digest: str, facts: dict) -> None:
    path = facts_path(d, j)
    path.parent.mkdir(exist_ok=True)
    with atomic_file(path, fsync=True) as tmp:
        tmp.write_text(json.dumps({"config_sha256": digest, **facts}))


def read_spot_facts(d: Path, j: int, digest: str) -> dict | None:
    """The facts an earlier run recorded for spot ``j`` with the same configuration, else None."""
    try:
        rec = json.loads(facts_path(d, j).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(rec, dict) or rec.pop("config_sha256", None) != digest:
        return None
    return rec


def remove_stale_temporaries(d: Path) -> None:
    """Delete temporary files a killed render left behind (``.spot_NNNNN.exr.*.tmp`` and the like, also in
    ``variance/``, ``error_bound/`` and ``.partial/``)."""
    for sub in (d, d / stack.VARIANCE_DIR, d / stack.ERROR_BOUND_DIR, d / PARTIAL_DIR):
        try:
            entries = list(sub.iterdir())
        except OSError:
            continue
        for p in entries:
            name = p.name
            if name.startswith((".spot_", f".{stack.MANIFEST_NAME}.", ".preview.png.", ".group_")) and p.is_file():
                try:
                    p.unlink()
                except OSError:
                    pass
