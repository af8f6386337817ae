"""Expanding a spec into items: parameters, seeds and the parameter hash of each.

Item ``k`` of a spec with ``G`` grid points is repeat ``k // G`` of grid point
``k % G`` (grid points in the order of the cartesian product, the first grid
key varying slowest), so raising ``repeats`` appends items and keeps the
existing ones. Every random process of item ``k`` is seeded from
``SeedSequence(seed, spawn_key=(k, stream))``:

========  ============================================================
stream    use
========  ============================================================
0         the ``random:`` draws, in the order the spec lists them
1         the render seed (``transient-mi render --seed``)
2         the detector seed (``detect_stack(seed=...)``)
========  ============================================================

so an item's values and bytes depend on the spec, the master seed and its
index only. The item's ``params_sha256`` is the SHA-256 of its canonical
JSON record (:func:`params_digest`): an item directory whose ``params.json``
holds the same hash was made from the same parameters.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from transient_core.errors import UserInputError

from .objects import MESH_NAME, OBJECT_KINDS
from .spec import DETECT_ARGS, DETECTOR_ENGINES, DatasetSpec, canonical_key, is_reference

#: Format of ``params.json``.
ITEM_FORMAT = "transient-mi-dataset-item"
ITEM_FORMAT_VERSION = 1
#: Keys of ``params.json`` left out of the hash (provenance that may differ between machines).
UNHASHED_KEYS = ("params_sha256", "scene_file", "commands")
#: Random streams of an item (see the module docstring).
STREAM_DRAWS, STREAM_RENDER, STREAM_DETECTOR = 0, 1, 2


def item_name(index: int) -> str:
    """Directory name of item ``index``: ``item_000042``."""
    return f"item_{index:06d}"


def item_seed(seed: int, index: int, stream: int) -> int:
    """A 32-bit seed for ``stream`` of item ``index`` (see the module docstring)."""
    ss = np.random.SeedSequence(int(seed), spawn_key=(int(index), int(stream)))
    return int(ss.generate_state(1, dtype=np.uint32)[0])


def item_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of item ``index``'s random draws."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(index), STREAM_DRAWS)))


def define_string(v: Any) -> str:
    """A parameter value as the string Mitsuba substitutes for ``$name``.

    Integers as written, floats by ``repr`` (shortest round-trip form),
    booleans as ``true``/``false``, lists of numbers comma-separated.
    """
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return ", ".join(define_string(x) for x in v)
    if isinstance(v, float):
        return repr(v)
    return str(v)


def params_digest(record: dict) -> str:
    """SHA-256 of an item record's canonical JSON, without :data:`UNHASHED_KEYS`."""
    core = {k: v for k, v in record.items() if k not in UNHASHED_KEYS}
    blob = json.dumps(core, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()
    return hashlib.sha256(blob).hexdigest()


@dataclass(frozen=True)
class Item:
    """One dataset item: its index, directory name and ``params.json`` record."""

    index: int
    record: dict

    @property
    def name(self) -> str:
        return self.record["item"]

    @property
    def params_sha256(self) -> str:
        return self.record["params_sha256"]

    @property
    def defines(self) -> dict[str, str]:
        return self.record["defines"]


def _resolve_references(values: dict[str, Any], spec: DatasetSpec, index: int) -> dict[str, Any]:
    out = dict(values)
    for key, v in values.items():
        ref = is_reference(v)
        if ref is None:
            continue
        where = f"{key} = {v!r}"
        target = canonical_key(where, ref, spec) if ref != "spp" else "spp"
        if target not in values:
            raise UserInputError(f"{where}: refers to {ref!r}, which the spec does not set "
                                 f"(set: {', '.join(values)})")
        if is_reference(values[target]) is not None:
            raise UserInputError(f"{where}: refers to {ref!r}, which is itself a reference; refer to a value")
        out[key] = values[target]
    return out


def _split(values: dict[str, Any], prefix: str) -> dict[str, Any]:
    n = len(prefix)
    return {k[n:]: v for k, v in values.items() if k.startswith(prefix)}


def _detector_record(spec: DatasetSpec, values: dict[str, Any], seed: int, index: int) -> dict | None:
    if not spec.has_detector:
        return None
    d = _split(values, "detector.")
    params = {k: v for k, v in d.items() if k not in DETECT_ARGS}
    pulses, exposure_s = d.get("pulses"), d.get("exposure_s")
    where = f"item {index}: detector"
    if pulses is not None and exposure_s is not None:
        raise UserInputError(f"{where}: pulses={pulses!r} and exposure_s={exposure_s!r}; give one photon budget")
    if pulses is not None:
        if isinstance(pulses, float) and pulses.is_integer():
            pulses = int(pulses)
        if isinstance(pulses, bool) or not isinstance(pulses, int) or pulses < 1:
            raise UserInputError(f"{where}.pulses={pulses!r}: expected an integer >= 1")
    if exposure_s is not None and (isinstance(exposure_s, (bool, str)) or not exposure_s > 0):
        raise UserInputError(f"{where}.exposure_s={exposure_s!r}: expected a time in seconds > 0")
    engine = d.get("engine", "auto")
    from spad_detector import DetectorParams

    if engine not in DETECTOR_ENGINES:
        raise UserInputError(f"{where}.engine={engine!r}: allowed {', '.join(DETECTOR_ENGINES)}")
    DetectorParams.from_dict(params).validate()
    return {"params": params, "pulses": pulses, "exposure_s": exposure_s, "engine": engine,
            "seed": item_seed(seed, index, STREAM_DETECTOR)}


def expand_items(spec: DatasetSpec, *, variant: str, scene_sha256: str) -> list[Item]:
    """Every item of ``spec``, in index order, with resolved and validated parameters.

    Parameters
    ----------
    spec : DatasetSpec
    variant : str
        The Mitsuba variant items are rendered in (recorded and hashed).
    scene_sha256 : str
        Hash of the scene file (recorded and hashed: editing the scene
        invalidates finished items).

    Raises
    ------
    UserInputError
        For an object or detector parameter that an item's values make
        invalid (the message names the item and the parameter).
    """
    grid_keys = list(spec.grid)
    grid_points = list(itertools.product(*(spec.grid[k] for k in grid_keys)))
    fixed = spec.fixed_values()
    kind = OBJECT_KINDS.get(spec.object_kind) if spec.object_kind else None
    items: list[Item] = []
    for repeat in range(spec.repeats):
        for g, point in enumerate(grid_points):
            index = repeat * len(grid_points) + g
            values = dict(fixed)
            values.update(zip(grid_keys, point))
            rng = item_rng(spec.seed, index)
            for key, dist in spec.random.items():
                values[key] = dist.draw(rng)
            values = _resolve_references(values, spec, index)
            defines = {k: define_string(v) for k, v in _split(values, "define.").items()}
            obj = None
            if kind is not None:
                try:
                    resolved = kind.resolve(_split(values, "object."))
                except UserInputError as e:
                    raise UserInputError(f"item {index} ({item_name(index)}): object.{e}") from None
                if spec.object_define is not None:
                    defines[spec.object_define] = MESH_NAME
                obj = {"kind": kind.name, "define": spec.object_define, "file": MESH_NAME, "params": resolved}
            spp = values["spp"]
            record = {
                "format": ITEM_FORMAT,
                "format_version": ITEM_FORMAT_VERSION,
                "item": item_name(index),
                "index": index,
                "repeat": repeat,
                "grid_index": g,
                "dataset_seed": spec.seed,
                "scene": spec.scene,
                "scene_sha256": scene_sha256,
                "variant": variant,
                "spp": spp,
                "render_seed": item_seed(spec.seed, index, STREAM_RENDER),
                "defines": dict(sorted(defines.items())),
                "object": obj,
                "detector": _detector_record(spec, values, spec.seed, index),
                "parameters": values,
                "varied": spec.varied_keys(),
            }
            if spec.noise_target is not None:  # only when set: items of a spec without it keep their hashes
                record["noise_target"] = spec.noise_target
            record["params_sha256"] = params_digest(record)
            record["scene_file"] = str(spec.scene_file)
            record["commands"] = redo_commands(record, spec)
            items.append(Item(index, record))
    return items


def redo_commands(record: dict, spec: DatasetSpec) -> list[str]:
    """Shell commands that redo the item's mesh and ideal render (run in the item directory).

    Run from the item directory, the render reads ``mesh.ply`` there and
    writes byte-identical spot files (the recorded ``-D`` values are the same).
    """
    cmds = []
    if record["object"] is not None:
        kind = OBJECT_KINDS[record["object"]["kind"]]
        cmds.append(kind.command(record["object"]["params"], MESH_NAME))
    out = "capture/ideal" if record["detector"] is not None else "capture"
    d = " ".join(f"-D {k}={_shell(v)}" for k, v in record["defines"].items())
    variant = f" --variant {record['variant']}"
    target = ""
    if record.get("noise_target") is not None:
        # the detector the target is judged with is the item's (params.json); `render` plans for the budget below
        # with its default detector, so this line redoes the item exactly only for that detector
        det = record["detector"]
        budget = (f" --pulses {det['pulses']}" if det.get("pulses") is not None else
                  f" --exposure-s {det['exposure_s']!r}" if det.get("exposure_s") is not None else "")
        target = f" --noise-target {record['noise_target']!r}{budget}"
    cmds.append(f"transient-mi render {_shell(str(spec.scene_file))} -o {out} {d} --spp {record['spp']} "
                f"--seed {record['render_seed']}{variant}{target}".replace("  ", " "))
    return cmds


def _shell(s: str) -> str:
    import shlex

    return shlex.quote(s)
