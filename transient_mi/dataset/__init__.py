"""Datasets of captures: many scenes and parameters, rendered in parallel on Dask.

A spec file (YAML or JSON, :mod:`~transient_mi.dataset.spec`) names a scene
and how its parameters vary (fixed values, a grid, seeded random draws), an
optional generated object (the procedural mannequin) and optional detector
settings. Every item becomes a complete directory ``items/item_NNNNNN/``
(capture, counts, ground-truth mesh, ``params.json``), and ``index.csv`` /
``index.jsonl`` list the finished items. Runs are idempotent and resumable;
see ``docs/dataset.md``.

Public API
----------
run_dataset      build a spec's missing items (local Dask cluster or a scheduler)
load_spec        read and validate a spec file -> DatasetSpec
parse_spec       validate a spec mapping -> DatasetSpec
expand_items     DatasetSpec -> list of Item (parameters, seeds, hashes)
item_status      is an item directory valid, damaged, or from other parameters?
read_index       the rows of a dataset's index.jsonl
"""

from .index import read_index
from .items import Item, expand_items, item_name, item_seed
from .runner import DatasetError, DatasetReport, run_dataset
from .spec import DatasetSpec, load_spec, parse_spec
from .worker import item_status

__all__ = [
    "run_dataset", "DatasetReport", "DatasetError", "load_spec", "parse_spec", "DatasetSpec", "expand_items",
    "Item", "item_name", "item_seed", "item_status", "read_index",
]
