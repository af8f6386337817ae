"""The dataset index: one row per finished item, as ``index.csv`` and ``index.jsonl``.

Both files are rebuilt from the finished items (never appended to), written
under a temporary name and renamed into place, so a reader sees either the
old or the new index, and an item appears at most once. Rows are in item
order; the index holds no timings or host names, so the same spec and seed
give the same index bytes.

Columns (see ``docs/dataset.md``): ``item``, ``index``, ``repeat``,
``grid_index``, ``params_sha256``, ``render_seed``, ``detector_seed``,
``spp`` (samples per pixel used), ``kind`` (``ideal`` or ``counts``), the
paths ``capture``, ``ideal`` and ``mesh`` relative to the dataset directory,
then every parameter (``spp`` requested as ``param.spp``, scene parameters as
``define.<name>``, ``object.<name>``, ``detector.<name>``) as given or drawn.
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

from transient_core.atomic import rename_into_place

from .worker import CAPTURE_NAME, PARAMS_NAME, RESULT_NAME

INDEX_CSV = "index.csv"
INDEX_JSONL = "index.jsonl"
FIXED_COLUMNS = ("item", "index", "repeat", "grid_index", "params_sha256", "render_seed", "detector_seed", "spp",
                 "render_noise_ratio", "estimator", "kind", "capture", "ideal", "mesh")


def item_row(item_dir: Path, root: Path) -> dict:
    """The index row of a finished item directory (paths relative to ``root``)."""
    rec = json.loads((item_dir / PARAMS_NAME).read_text())
    res = json.loads((item_dir / RESULT_NAME).read_text())
    rel = item_dir.relative_to(root).as_posix()
    det = rec.get("detector")
    capture = f"{rel}/{CAPTURE_NAME}"
    kind = res.get("kind", "counts" if det else "ideal")
    ideal = f"{rel}/{res['ideal']}" if res.get("ideal") else (f"{capture}/ideal" if det else capture)
    row = {
        "item": rec["item"],
        "index": rec["index"],
        "repeat": rec["repeat"],
        "grid_index": rec["grid_index"],
        "params_sha256": rec["params_sha256"],
        "render_seed": rec["render_seed"],
        "detector_seed": res.get("detector_seed", det["seed"] if det else None),
        "spp": res.get("spp_used", rec["spp"]),
        "render_noise_ratio": res.get("render_noise_ratio"),
        "estimator": res.get("estimator", "monte_carlo"),  # which estimator made the capture
        "kind": kind,
        "capture": capture,
        "ideal": ideal,
        "mesh": f"{rel}/{rec['object']['file']}" if rec.get("object") else None,
    }
    for k, v in rec["parameters"].items():
        row["param.spp" if k == "spp" else k] = v
    return row


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, dict)):
        return json.dumps(v, separators=(",", ":"))
    if isinstance(v, float):
        return repr(v)
    return str(v)


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    rename_into_place(tmp, path)


def write_index(root: Path, rows: dict[str, dict]) -> tuple[Path, Path]:
    """Write ``index.csv`` and ``index.jsonl`` in ``root`` from ``rows`` (item name -> row).

    Returns
    -------
    (Path, Path)
        The CSV and JSON-lines files.
    """
    ordered = [rows[k] for k in sorted(rows, key=lambda k: rows[k]["index"])]
    columns = list(FIXED_COLUMNS)
    for r in ordered:
        for k in r:
            if k not in columns:
                columns.append(k)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in ordered:
        w.writerow([_cell(r.get(c)) for c in columns])
    csv_path, jsonl_path = root / INDEX_CSV, root / INDEX_JSONL
    _atomic_write(csv_path, buf.getvalue().encode())
    lines = "".join(json.dumps(r, separators=(",", ":"), allow_nan=False) + "\n" for r in ordered)
    _atomic_write(jsonl_path, lines.encode())
    return csv_path, jsonl_path


def read_index(root: Path) -> list[dict]:
    """The rows of ``root/index.jsonl`` (typed values), in item order."""
    p = Path(root) / INDEX_JSONL
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]
