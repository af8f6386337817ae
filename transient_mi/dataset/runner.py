"""Running a dataset on Dask: validation, scheduling, resume, the index.

One module on purpose (over 500 lines): the steps below share the run's state (spec, lock, index,
resume records) and read in order as one procedure.

:func:`run_dataset` does, in order:

1. read and validate the spec, expand every item (object and detector
   parameters of every item are checked), check the output location;
2. load the scene once with the first item's values (and once per value at
   the ends of every varied scene parameter, at most :data:`MAX_PROBES`
   loads) without writing anything: unknown ``-D`` names and bad values fail
   here, before any work;
3. look at the items already in the output: valid ones (same parameter
   hash, every file present) are skipped; items made from other parameters
   stop the run with an error; damaged ones are redone;
4. start a local Dask cluster (``--workers`` processes, one task at a time
   each, drjit threads = cores / workers) or connect to ``--scheduler``,
   lock the output directory, delete temporary directories left by
   interrupted runs, submit the missing items and follow them with a
   progress bar, rewriting the index as items finish. The cluster's warnings
   (a worker process killed by a signal or restarted, a worker lost) go to
   ``cluster.log`` in the output directory, made by the first one only.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import re
import shutil
import tempfile
import time
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from transient_core.progress import progress_bar
from transient_core.atomic import rename_into_place
from transient_core.errors import UserInputError

from .index import INDEX_CSV, INDEX_JSONL, item_row, write_index
from .items import Item, define_string, expand_items
from .objects import MESH_NAME, OBJECT_KINDS
from .spec import DatasetSpec, load_spec
from .worker import TMP_PREFIX, build_item, host_threads, item_status, resolver_first

DATASET_FORMAT = "transient-mi-dataset"
DATASET_FORMAT_VERSION = 1
DATASET_JSON = "dataset.json"
ITEMS_DIR = "items"
LOCK_NAME = ".dataset.lock"
#: The cluster's warnings of a run (appended; created by the first warning).
CLUSTER_LOG = "cluster.log"
#: Most scene loads spent on checking the ends of varied parameters before work.
MAX_PROBES = 64
#: Seconds between rewrites of the index while items finish.
INDEX_EVERY_S = 10.0
_ITEM_DIR = re.compile(r"^item_(\d{6,})$")

log = logging.getLogger(__name__)


class DatasetError(RuntimeError):
    """Some items failed (after the others were built); the message lists them."""


@dataclass
class DatasetReport:
    """What :func:`run_dataset` did."""

    out_dir: Path
    n_items: int
    existed: int = 0
    built: int = 0
    redone_damaged: int = 0
    #: (item, worker that redid it, earlier unfinished attempts) for every item built again after a worker died
    retried: list[tuple[str, str, list[str]]] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)
    cleaned_tmp: int = 0
    elapsed_s: float = 0.0
    cluster: str = ""
    dry_run: bool = False
    items: list[Item] = field(default_factory=list)
    #: Largest rendering / photon noise ratio over the indexed items with counts (None if unknown).
    render_noise_max: float | None = None
    render_noise_items: int = 0

    def summary(self) -> str:
        if self.dry_run:
            todo = self.n_items - self.existed
            return (f"dry run: {self.n_items} items, {self.existed} already done, {todo} to build "
                    f"into {self.out_dir}; nothing written")
        s = (f"dataset {self.out_dir}: {self.n_items} items ({self.existed} already done, {self.built} built, "
             f"{len(self.failed)} failed) in {self.elapsed_s:.1f} s")
        if self.cluster:
            s += f" on {self.cluster}"
        if self.retried:
            s += f"; {len(self.retried)} item(s) redone after a worker died ({', '.join(r[0] for r in self.retried)})"
        s += f"; index {self.out_dir / INDEX_CSV}"
        if self.render_noise_max is not None:
            over = self.render_noise_max > 0.1
            s += (f"; rendering/photon noise up to {self.render_noise_max:.3g} over {self.render_noise_items} items"
                  + (f" (above 0.1 by a factor {self.render_noise_max / 0.1:.3g}: raise spp, see docs/noise.md)"
                     if over else " (below 0.1)"))
        return s


# ----------------------------------------------------------------------------- output


def check_output(out: Path) -> None:
    """Fail unless ``out`` can hold a dataset (creates nothing)."""
    if out.exists() and not out.is_dir():
        raise UserInputError(f"-o {out}: exists and is not a directory")
    if out.exists():
        entries = [p.name for p in out.iterdir() if p.name != LOCK_NAME]
        if entries and not ((out / DATASET_JSON).exists() or (out / ITEMS_DIR).is_dir()):
            raise UserInputError(f"-o {out}: directory exists, is not empty and holds no transient-mi dataset "
                                 f"(no {DATASET_JSON}); choose a new or empty directory")
        probe_in = out
    else:
        probe_in = out.parent if str(out.parent) else Path(".")
        if not probe_in.is_dir():
            raise UserInputError(f"-o {out}: parent directory {probe_in} does not exist")
    try:  # a real probe: permission bits say little for root or read-only mounts
        os.rmdir(tempfile.mkdtemp(dir=probe_in, prefix=".transient-mi-probe-"))
    except OSError as e:
        raise UserInputError(f"-o {out}: cannot create a directory in {probe_in} ({e.strerror})") from None


@contextmanager
def output_lock(out: Path):
    """Hold an exclusive lock on ``out`` for the ``with`` block (one run per dataset directory)."""
    fd = os.open(out / LOCK_NAME, os.O_CREAT | os.O_RDWR, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UserInputError(f"-o {out}: another transient-mi dataset run is writing this directory "
                                 f"(it holds {out / LOCK_NAME}); wait for it or stop it") from None
        yield
    finally:
        os.close(fd)


def clean_temporaries(items_dir: Path) -> int:
    """Delete temporary item directories left by killed workers or interrupted runs, and the temporary index and
    dataset files (``.index.csv.tmp-PID``) of a run killed while writing them beside ``items_dir``; return how
    many."""
    n = 0
    if items_dir.is_dir():
        for p in items_dir.iterdir():
            if p.name.startswith(TMP_PREFIX):
                shutil.rmtree(p, ignore_errors=True)
                n += 1
    if items_dir.parent.is_dir():
        for p in items_dir.parent.iterdir():
            if re.fullmatch(r"\..+\.tmp-\d+", p.name) and p.is_file():
                p.unlink(missing_ok=True)
    return n


def _atomic_json(path: Path, obj) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(obj, indent=2, allow_nan=False) + "\n")
    rename_into_place(tmp, path)


# ----------------------------------------------------------------------------- scene checks


def scene_parameters(scene_file: Path) -> set[str] | None:
    """Names of the ``$name`` parameters an XML scene uses, or None when it includes other files."""
    text = Path(scene_file).read_text(errors="replace")
    text = re.sub(r"<!--.*?-->", "", text, flags=re.S)
    if re.search(r"<include\b", text):
        return None
    names = set(re.findall(r"\$([A-Za-z_][A-Za-z0-9_]*)", text))
    names |= set(re.findall(r"<default\s+name\s*=\s*[\"']([A-Za-z_][A-Za-z0-9_]*)[\"']", text))
    return names


def _section_of(spec: DatasetSpec, key: str) -> str:
    name = key[len("define."):]
    if key in spec.grid:
        return f"grid.{name}"
    if key in spec.random:
        return f"random.{name}"
    return f"defines.{name}"


def validate_scene(spec: DatasetSpec, items: list[Item]) -> int:
    """Load the scene with the first item's values, and at the ends of varied scene parameters.

    Nothing is written except the first item's mesh, into a temporary folder.
    Returns the number of scene loads.

    Raises
    ------
    UserInputError
        A ``-D`` name the scene does not use, or a value the scene rejects
        (the message names the spec key and the value).
    """
    from transient_mi.render_capture import prepare_render

    scene_file = spec.scene_file
    known = scene_parameters(scene_file)
    define_keys = [k for k in list(spec.fixed_values()) + spec.varied_keys() if k.startswith("define.")]
    if known is not None:
        for key in define_keys:
            name = key[len("define."):]
            if name not in known:
                raise UserInputError(f"{_section_of(spec, key)}: scene {scene_file.name} has no parameter ${name}; "
                                     f"its parameters: {', '.join(sorted(known)) or 'none'}")
        if spec.object_kind is not None and spec.object_define is not None and spec.object_define not in known:
            raise UserInputError(f"object.define: scene {scene_file.name} has no parameter ${spec.object_define} "
                                 f"to receive the mesh path; its parameters: {', '.join(sorted(known)) or 'none'}")
    if spec.object_kind is not None and (scene_file.parent / MESH_NAME).exists():
        raise UserInputError(f"object: the scene's folder {scene_file.parent} holds a file named {MESH_NAME}, which "
                             f"Mitsuba would load instead of each item's generated mesh; rename that file")
    first = items[0]
    n_loads = 0
    with tempfile.TemporaryDirectory(prefix="transient-mi-dataset-check-") as td:
        tdir = Path(td)
        if first.record["object"] is not None:
            kind = OBJECT_KINDS[first.record["object"]["kind"]]
            kind.write(tdir / MESH_NAME, first.record["object"]["params"])

        def load(defines: dict[str, str], what: str) -> None:
            nonlocal n_loads
            try:
                with resolver_first(tdir):
                    job = prepare_render(scene_file, tdir / f"capture{n_loads}", defines=defines,
                                         spp=first.record["spp"], seed=first.record["render_seed"],
                                         variant=first.record["variant"])
            except UserInputError as e:
                raise UserInputError(f"{what}: {e}") from None
            n_loads += 1
            if job.detect_kwargs is not None and spec.has_detector:
                raise UserInputError(f"detector: scene {scene_file.name} has a spad_film, which runs the detector "
                                     "itself; remove the spec's detector settings (vary the film's parameters "
                                     "as scene -D values instead) or use a transient_film")

        load(first.defines, f"item 0 ({first.name})")
        seen = {tuple(sorted(first.defines.items()))}
        for key in spec.varied_keys():
            if not key.startswith("define."):
                continue
            name = key[len("define."):]
            probes = spec.grid[key] if key in spec.grid else spec.random[key].probe_values()
            for v in probes:
                d = dict(first.defines, **{name: define_string(v)})
                sig = tuple(sorted(d.items()))
                if sig in seen or n_loads >= MAX_PROBES:
                    continue
                seen.add(sig)
                load(d, f"{_section_of(spec, key)} = {v!r}")
    return n_loads


# ----------------------------------------------------------------------------- existing items


@dataclass
class Existing:
    valid: set[str] = field(default_factory=set)
    damaged: set[str] = field(default_factory=set)


def scan_existing(out: Path, items: list[Item]) -> Existing:
    """Classify the item directories already in ``out/items``.

    Raises
    ------
    UserInputError
        When some were made from other parameters, or are not items of this spec.
    """
    ex = Existing()
    items_dir = out / ITEMS_DIR
    if not items_dir.is_dir():
        return ex
    by_name = {it.name: it for it in items}
    other, foreign = [], []
    for p in sorted(items_dir.iterdir()):
        if not _ITEM_DIR.match(p.name) or not p.is_dir():
            continue
        it = by_name.get(p.name)
        if it is None:
            foreign.append(p.name)
            continue
        st = item_status(p, it.params_sha256)
        if st == "valid":
            ex.valid.add(p.name)
        elif st == "other":
            other.append(p.name)
        else:
            ex.damaged.add(p.name)
    if other:
        raise UserInputError(
            f"-o {out}: {len(other)} existing item(s) were made from other parameters ({', '.join(other[:3])}"
            f"{', ...' if len(other) > 3 else ''}): the spec, its seed or the scene changed since; "
            "use a new output directory")
    if foreign:
        raise UserInputError(
            f"-o {out}: holds {len(foreign)} item(s) that this spec does not have ({', '.join(foreign[:3])}"
            f"{', ...' if len(foreign) > 3 else ''}; the spec has {len(items)} items); use a new output directory")
    return ex


# ----------------------------------------------------------------------------- Dask


class DaskConnection:
    """A Dask client on ``scheduler`` if given, else on a new local cluster of ``workers`` processes."""

    def __init__(self, scheduler: str | None, workers: int | None):
        from distributed import Client, LocalCluster

        self.cluster = None
        if scheduler:
            try:  # waits up to dask's distributed.comm.timeouts.connect (30 s by default)
                self.client = Client(scheduler)
            except (OSError, TimeoutError, ValueError) as e:
                raise UserInputError(f"--scheduler {scheduler}: cannot connect ({type(e).__name__}: {e})") from None
            self.n_workers = len(self.client.scheduler_info().get("workers", {}))
            self.description = f"scheduler {scheduler} ({self.n_workers} workers at the start)"
        else:
            self.cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                        dashboard_address=None, silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
            self.n_workers = int(workers)
            self.description = f"a local cluster of {workers} worker processes"

    def close(self) -> None:
        """Close the client and stop the local cluster's workers (idempotent)."""
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None


def check_cluster(client, scheduler: str, scene_file: Path, out: Path) -> int:
    """Check an external cluster before submitting: importable transient_mi, shared files.

    Dask deserialises tasks on the scheduler, so the scheduler and every
    worker need transient-mi installed; workers read the scene and write the
    items, so they must see the same paths. Returns the number of workers.

    Raises
    ------
    UserInputError
        Naming what is missing where.
    """
    import importlib.util
    import os.path

    if client.run_on_scheduler(importlib.util.find_spec, "transient_mi") is None:
        raise UserInputError(f"--scheduler {scheduler}: the scheduler cannot import transient_mi; start "
                             "`dask scheduler` in an environment where transient-mi is installed (Dask reads the "
                             "tasks there)")
    specs = client.run(importlib.util.find_spec, "transient_mi")
    bad = sorted(a for a, sp in specs.items() if sp is None)
    if bad:
        raise UserInputError(f"--scheduler {scheduler}: {len(bad)} of {len(specs)} workers cannot import transient_mi "
                             f"({', '.join(bad[:3])}); start `dask worker` where transient-mi is installed")
    for what, fn, path in (("scene file", os.path.isfile, scene_file), ("output folder", os.path.isdir, out)):
        seen = client.run(fn, str(path))
        blind = sorted(a for a, ok in seen.items() if not ok)
        if blind:
            raise UserInputError(f"--scheduler {scheduler}: {len(blind)} of {len(seen)} workers cannot see the "
                                 f"{what} {path} ({', '.join(blind[:3])}); workers need a shared filesystem "
                                 "with the same paths")
    return len(specs)


def default_workers() -> int:
    """Local worker processes by default: Dask's own split of the cores into processes.

    Up to 4 cores, one process per core (each rendering with one drjit
    thread); above, about sqrt(cores) processes sharing the cores as drjit
    threads (fewer copies of a large render's memory). On the 2-core machine
    we measured, 2 x 1 and 1 x 2 gave the same items per hour within the
    run-to-run noise (docs/dataset.md).
    """
    from dask.system import CPU_COUNT
    from distributed.deploy.utils import nprocesses_nthreads

    return max(1, nprocesses_nthreads(int(CPU_COUNT))[0])


def _threads_plan(client, scheduler: str | None, workers: int, threads_per_worker: int | None):
    """drjit threads for each worker: an int, or hostname -> int for an external cluster."""
    if threads_per_worker:
        return int(threads_per_worker)
    if not scheduler:
        from dask.system import CPU_COUNT

        return max(1, int(CPU_COUNT) // max(1, workers))
    info = client.run(host_threads)  # worker address -> (hostname, cores)
    per_host = Counter(h for h, _ in info.values())
    cores = {h: c for h, c in info.values()}
    return {h: max(1, cores[h] // per_host[h]) for h in per_host}


# ----------------------------------------------------------------------------- the run


def run_dataset(spec_file: str | Path, out_dir: str | Path, *, scheduler: str | None = None,
                workers: int | None = None, threads_per_worker: int | None = None, dry_run: bool = False,
                progress: bool | None = None, echo=None) -> DatasetReport:
    """Build every missing item of a spec into ``out_dir`` (see the module docstring).

    Parameters
    ----------
    spec_file : path
        YAML or JSON spec (:mod:`transient_mi.dataset.spec`).
    out_dir : path
        Dataset directory (created; its parent must exist).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); default: a
        local cluster.
    workers : int, optional
        Worker processes of the local cluster (default: :func:`default_workers`).
    threads_per_worker : int, optional
        drjit threads in each worker process (default: cores / workers on
        each host).
    dry_run : bool
        Validate and report the plan; write nothing.
    progress : bool, optional
        Force the progress bar on or off.
    echo : callable, optional
        Called with one-line status messages.

    Raises
    ------
    UserInputError
        Anything wrong with the spec, the scene or the output, before any work.
    DatasetError
        Some items failed; the others were built and indexed.
    """
    import transient_mi as tm
    from transient_mi.scene_io import file_sha256

    say = echo or (lambda msg: None)
    t0 = time.perf_counter()
    out = Path(out_dir)
    spec = load_spec(spec_file)
    if workers is not None and workers < 1:
        raise UserInputError(f"--workers {workers}: must be >= 1")
    if threads_per_worker is not None and threads_per_worker < 1:
        raise UserInputError(f"--threads-per-worker {threads_per_worker}: must be >= 1")
    if scheduler is not None and workers is not None:
        raise UserInputError(f"--workers {workers} with --scheduler {scheduler}: the external cluster has its own "
                             "workers; give one of them")
    check_output(out)
    variant = spec.variant or tm.variant()
    items = expand_items(spec, variant=variant, scene_sha256=file_sha256(spec.scene_file))
    validate_scene(spec, items)
    existing = scan_existing(out, items)
    report = DatasetReport(out, len(items), existed=len(existing.valid), items=items)
    todo = [it for it in items if it.name not in existing.valid]
    if dry_run:
        report.dry_run = True
        return report
    if not todo:
        with _locked_output(out):
            report.cleaned_tmp = clean_temporaries(out / ITEMS_DIR)
            _write_dataset_json(out, spec, len(items), variant)
            rows = _rows(out, items)
            write_index(out, rows)
        _noise_summary(report, rows)
        report.elapsed_s = time.perf_counter() - t0
        return report
    workers = workers or (None if scheduler else default_workers())
    conn = DaskConnection(scheduler, workers)  # connect first: a bad address fails before anything is written
    try:
        report.cluster = conn.description
        if scheduler:  # before anything is written
            where = out.resolve() if out.exists() else out.resolve().parent
            if check_cluster(conn.client, scheduler, spec.scene_file, where) == 0:
                say(f"--scheduler {scheduler} has no workers yet: items start when workers join")
        with _locked_output(out):
            threads = _threads_plan(conn.client, scheduler, conn.n_workers, threads_per_worker)
            items_dir = out / ITEMS_DIR
            items_dir.mkdir(exist_ok=True)
            report.cleaned_tmp = clean_temporaries(items_dir)
            for name in sorted(existing.damaged):
                _remove_item(items_dir / name)
            report.redone_damaged = len(existing.damaged)
            _write_dataset_json(out, spec, len(items), variant)
            say(f"{len(items)} items: {len(existing.valid)} already done, {len(todo)} to build on {conn.description}")
            with cluster_log(out):  # (the workers' shutdown included)
                try:
                    _submit_and_wait(conn.client, todo, items_dir, str(spec.scene_file), threads, report, out,
                                     items, progress, say)
                finally:
                    conn.close()  # local workers stop before their temporary directories are removed
                    report.cleaned_tmp += clean_temporaries(items_dir)
                    rows = _rows(out, items)
                    write_index(out, rows)
                    _noise_summary(report, rows)
    finally:
        conn.close()
    report.elapsed_s = time.perf_counter() - t0
    if report.failed:
        first = "; ".join(f"{n}: {m}" for n, m in report.failed[:3])
        raise DatasetError(f"{len(report.failed)} of {len(todo)} items failed ({first}"
                           f"{'; ...' if len(report.failed) > 3 else ''}); the others are in {out}; "
                           "rerun the same command to retry the failed ones")
    return report


def _noise_summary(report: DatasetReport, rows: dict) -> None:
    """The largest rendering / photon noise ratio over the indexed items (docs/noise.md)."""
    ratios = [r["render_noise_ratio"] for r in rows.values() if r.get("render_noise_ratio") is not None]
    report.render_noise_items = len(ratios)
    report.render_noise_max = max(ratios) if ratios else None


@contextmanager
def _locked_output(out: Path):
    out.mkdir(exist_ok=True)
    with output_lock(out):
        yield


def _cluster_record(record: logging.LogRecord) -> bool:
    """Warnings and errors, and the nanny's word on a worker process that ended badly (``Worker process PID was
    killed by signal N`` / ``exited with status N``, which Dask logs at INFO)."""
    return record.levelno >= logging.WARNING or (
        record.name == "distributed.nanny" and record.getMessage().startswith("Worker process "))


@contextmanager
def cluster_log(out: Path):
    """Append the ``distributed`` loggers' warnings of this process (the local cluster's nannies and scheduler: a
    worker process killed by a signal, restarted or lost; :func:`_cluster_record`) to ``out/cluster.log`` for the
    ``with`` block. The file is opened by the first warning, so a quiet run leaves none; the console keeps only
    errors."""
    handler = logging.FileHandler(out / CLUSTER_LOG, delay=True)
    handler.addFilter(_cluster_record)
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s: %(message)s"))
    logger = logging.getLogger("distributed")
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        handler.close()


def _remove_item(path: Path) -> None:
    """Take a damaged item out of the way atomically (rename), then delete it."""
    import secrets

    tmp = path.with_name(f"{TMP_PREFIX}{path.name}-damaged-{secrets.token_hex(4)}")
    os.rename(path, tmp)
    shutil.rmtree(tmp, ignore_errors=True)


def _write_dataset_json(out: Path, spec: DatasetSpec, n_items: int, variant: str) -> None:
    _atomic_json(out / DATASET_JSON, {
        "format": DATASET_FORMAT,
        "format_version": DATASET_FORMAT_VERSION,
        "spec": spec.to_dict(),
        "spec_file": str(spec.spec_file) if spec.spec_file else None,
        "scene_file": str(spec.scene_file),
        "variant": variant,
        "n_items": n_items,
        "items_dir": ITEMS_DIR,
        "index": [INDEX_CSV, INDEX_JSONL],
    })


def _rows(out: Path, items: list[Item]) -> dict[str, dict]:
    rows = {}
    for it in items:
        d = out / ITEMS_DIR / it.name
        if item_status(d, it.params_sha256) == "valid":
            rows[it.name] = item_row(d, out)
    return rows


def _retry_line(name: str, res: dict, out: Path) -> str:
    """One line on an item built again: which attempts were left, and whether their workers died or still ran
    (the scheduler took a worker on this host for lost; its unfinished attempt is discarded)."""
    earlier, alive = res["earlier_attempts"], set(res.get("earlier_alive", ()))
    why = (f"the scheduler lost the worker of {', '.join(sorted(alive))}, still running on its host"
           if alive else "a worker died in it")
    return (f"{name}: redone by worker {res['worker']} after {len(earlier)} unfinished attempt(s) ({why}; left "
            f"{', '.join(earlier)}; the cluster's warnings, if any: {out / CLUSTER_LOG})")


def _submit_and_wait(client, todo, items_dir, scene_file, threads, report, out, items, progress, say) -> None:
    from distributed import as_completed

    futures = {}
    for it in todo:
        task = {"record": it.record, "items_dir": str(items_dir.resolve()), "scene_file": scene_file,
                "threads": threads}
        fut = client.submit(build_item, task, key=f"transient-mi-{it.name}-{it.params_sha256[:12]}", pure=False)
        futures[fut] = it
    rows = {n: item_row(items_dir / n, out) for n in (set(i.name for i in items) - set(i.name for i in todo))}
    last_index = time.monotonic()
    try:
        with progress_bar(f"dataset {out.name}", total=len(todo),
                          disable=None if progress is None else not progress) as advance:
            for fut in as_completed(list(futures)):
                it = futures[fut]
                try:
                    res = fut.result()
                except Exception as e:  # noqa: BLE001 - an item failed: record it, keep the others going
                    msg = str(e) if type(e).__name__ == "ItemError" else f"{type(e).__name__}: {e}"
                    report.failed.append((it.name, msg.replace("\n", " ")))
                else:
                    if res.get("earlier_attempts"):
                        report.retried.append((it.name, res["worker"], list(res["earlier_attempts"])))
                        say(_retry_line(it.name, res, out))
                    if res["status"] == "built":
                        report.built += 1
                    else:
                        report.existed += 1
                    rows[it.name] = item_row(items_dir / it.name, out)
                advance(1)
                if time.monotonic() - last_index > INDEX_EVERY_S:
                    write_index(out, rows)
                    last_index = time.monotonic()
    finally:
        for fut in futures:
            fut.release()
    report.failed.sort()
