"""Building one dataset item (runs in a Dask worker process).

An item is built in a temporary sibling directory,
``items/.tmp-item_NNNNNN-<host>-<pid>-<random>``, and renamed to
``items/item_NNNNNN`` only when everything is written, so a directory with
a final name is always complete. Inside, in this order:

1. ``mesh.ply``: the generated object (when the spec has one);
2. ``capture/``: the ideal capture, rendered by :mod:`transient_mi.render_capture`
   with the item's ``-D`` values, spp and render seed; with detector
   settings in the spec (or a ``spad_film`` in the scene) the counts capture
   goes to ``capture/`` and the ideal one to ``capture/ideal/`` (the layout
   of ``transient-mi render`` with a ``spad_film``);
3. ``params.json``: the item record (see :mod:`transient_mi.dataset.items`);
4. ``result.json``: timings, the worker, and the size of every file
   (written last: the item's completion record).

A killed worker leaves only a temporary directory, which the next run (or
the end of this one) deletes; Dask re-runs the item elsewhere. If two
attempts of the same item race (a worker thought dead was not), the second
rename fails and the finished item is kept.

The scene is loaded with one drjit thread (see :func:`transient_mi.scene_io.single_threaded`) and
rendered with all of the worker's threads. The mesh reaches the scene as the relative path ``mesh.ply`` (the item
directory is put first on Mitsuba's file resolver while the scene loads),
so the recorded ``-D`` values, and with them the bytes of the EXR files, do
not depend on where the dataset is written.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import socket
import threading
import time
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

from transient_core.atomic import rename_into_place
from transient_core.errors import UserInputError
from transient_core.fault import point as _fault

from .items import params_digest
from .objects import MESH_NAME, OBJECT_KINDS

PARAMS_NAME = "params.json"
RESULT_NAME = "result.json"
CAPTURE_NAME = "capture"
TMP_PREFIX = ".tmp-"
#: Test hook: ``"<item index>:<flag file>"`` makes the worker SIGKILL itself in
#: the middle of that item (after its first spot file is written), once: the
#: flag file records that it happened. For tests of recovery only.
KILL_ENV = "TRANSIENT_MI_DATASET_TEST_KILL"
#: Overrides the drjit thread count of every worker process.
THREADS_ENV = "TRANSIENT_MI_DRJIT_THREADS"

# One render at a time per process: Mitsuba's file resolver and the
# variant are process-wide, and drjit's own thread pool already uses the cores.
_PROCESS_LOCK = threading.Lock()
_THREADS_SET: int | None = None


class ItemError(RuntimeError):
    """An item could not be built (the message names the item and the cause)."""


def _json_bytes(obj) -> bytes:
    return (json.dumps(obj, indent=2, sort_keys=False, allow_nan=False) + "\n").encode()


def _write_json(path: Path, obj) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(_json_bytes(obj))
        f.flush()
        os.fsync(f.fileno())
    rename_into_place(tmp, path)


def configure_threads(threads: int | None) -> int | None:
    """Set drjit's thread count for this process (``$TRANSIENT_MI_DRJIT_THREADS`` wins; once per value) and numba's
    for the calling thread (numba's count is the thread's own: set for every item), the quadrature's kernels then
    running on as many threads as the worker's share of the cores, not on every core beside the other workers."""
    global _THREADS_SET
    env = os.environ.get(THREADS_ENV)
    n = int(env) if env else threads
    if n and n != _THREADS_SET:
        import drjit as dr

        dr.set_thread_count(int(n))
        _THREADS_SET = int(n)
    if n:
        import numba

        numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))
    return _THREADS_SET


@contextmanager
def resolver_first(directory: Path):
    """Put ``directory`` first on Mitsuba's file resolver (process-wide) for the ``with`` block."""
    import mitsuba as mi

    fr = mi.file_resolver()
    fr.prepend(str(directory))
    try:
        yield
    finally:
        for i in range(len(fr)):
            if str(fr[i]) == str(directory):
                del fr[i]
                break


def host_threads() -> tuple[str, int]:
    """``(hostname, usable cores)`` of this process (for choosing drjit thread counts)."""
    from dask.system import CPU_COUNT

    return socket.gethostname(), int(CPU_COUNT)


def list_files(root: Path) -> dict[str, int]:
    """Relative path -> size in bytes of every file under ``root`` (sorted)."""
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file():
            out[p.relative_to(root).as_posix()] = p.stat().st_size
    return out


def item_status(item_dir: Path, expected_sha256: str | None = None) -> str:
    """State of a finished item directory.

    Returns
    -------
    str
        ``"valid"`` (params hash as expected, every file of ``result.json``
        present with its size), ``"other"`` (made from other parameters:
        its hash differs), ``"damaged"`` (params match but files are missing
        or unreadable), or ``"missing"``.
    """
    if not item_dir.is_dir():
        return "missing"
    try:
        rec = json.loads((item_dir / PARAMS_NAME).read_text())
        digest = rec.get("params_sha256")
        if digest != params_digest(rec):
            return "damaged"
    except (OSError, ValueError, AttributeError):
        return "damaged"
    if expected_sha256 is not None and digest != expected_sha256:
        return "other"
    try:
        res = json.loads((item_dir / RESULT_NAME).read_text())
        files = res["files"]
        for rel, size in files.items():
            if (item_dir / rel).stat().st_size != size:
                return "damaged"
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return "damaged"
    return "valid"


def _kill_hook(index: int, tmp: Path):
    spec = os.environ.get(KILL_ENV)
    if not spec:
        return None
    want, _, flag = spec.partition(":")
    if int(want) != index or not flag:
        return None

    def on_spot(j: int) -> None:
        try:
            fd = os.open(flag, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            return  # killed once already: this is the retry
        # what the item looked like when the worker died: for the test to check it was mid-item
        state = {"pid": os.getpid(), "tmp_dir": str(tmp), "files": sorted(list_files(tmp))}
        os.write(fd, json.dumps(state).encode())
        os.fsync(fd)
        os.close(fd)
        os.kill(os.getpid(), signal.SIGKILL)

    return on_spot


def build_item(task: dict) -> dict:
    """Build one item (the Dask task). Skips work when the item is already valid.

    Parameters
    ----------
    task : dict
        ``record`` (the item's params.json content), ``items_dir``,
        ``scene_file``, ``threads`` (drjit threads per hostname, or an int).

    Returns
    -------
    dict
        ``item``, ``status`` (``"built"`` or ``"existed"``), ``worker``,
        ``total_time_s`` and (unless it existed before) ``earlier_attempts``: the
        temporary directories of unfinished earlier attempts at this item
        (a worker died in it), which make this run a retry, and
        ``earlier_alive``: those whose process still runs on this host (the
        scheduler took its worker for lost: :func:`attempt_alive`).

    Raises
    ------
    ItemError
        When rendering, meshing or detection fails (the message names the item).
    """
    rec = task["record"]
    items_dir = Path(task["items_dir"])
    final = items_dir / rec["item"]
    with _PROCESS_LOCK:
        threads = task.get("threads")
        if isinstance(threads, dict):
            threads = threads.get(socket.gethostname())
        configure_threads(threads)
        if item_status(final, rec["params_sha256"]) == "valid":
            return {"item": rec["item"], "status": "existed", "worker": _worker_id(), "total_time_s": 0.0}
        # temporary directories of this item already there are earlier attempts that did not finish (their
        # worker died and the scheduler gave the item to this one): the runner logs the retry
        earlier = sorted(p.name for p in items_dir.glob(f"{TMP_PREFIX}{rec['item']}-*"))
        alive = [name for name in earlier if attempt_alive(name)]
        tmp = items_dir / f"{TMP_PREFIX}{rec['item']}-{socket.gethostname()}-{os.getpid()}-{secrets.token_hex(4)}"
        tmp.mkdir()
        try:
            result = _build_into(tmp, rec, Path(task["scene_file"]))
            try:
                _fault("before_rename", final)
                os.rename(tmp, final)
                _fault("after_rename", final)
            except OSError:
                # another attempt finished first (or a damaged item sits there): keep a valid one
                if item_status(final, rec["params_sha256"]) != "valid":
                    raise ItemError(f"{rec['item']}: cannot move the finished item into place: {final} exists "
                                    "and is not a valid item") from None
                shutil.rmtree(tmp, ignore_errors=True)
                return {"item": rec["item"], "status": "existed", "worker": _worker_id(), "total_time_s": 0.0,
                        "earlier_attempts": earlier, "earlier_alive": alive}
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return {"item": rec["item"], "status": "built", "worker": result["worker"],
            "total_time_s": result["total_time_s"], "earlier_attempts": earlier, "earlier_alive": alive}


def attempt_alive(tmp_name: str) -> bool:
    """Whether the process that made the temporary item directory ``tmp_name`` (``.tmp-<item>-<host>-<pid>-<hex>``)
    runs on this host now (another process than this one). False for another host: it cannot be asked."""
    parts = tmp_name.rsplit("-", 2)
    if len(parts) != 3 or not parts[1].isdigit():
        return False
    pid, host = int(parts[1]), parts[0].split("-", 2)[-1]
    if host != socket.gethostname() or pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # (it exists, owned by another user)
        pass
    return True


def _worker_id() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _build_into(tmp: Path, rec: dict, scene_file: Path) -> dict:
    """Write the item's files into ``tmp`` (see the module docstring); return result.json's content."""
    from transient_mi.render_capture import prepare_render, run_render

    t_start = time.perf_counter()
    times = {}
    where = rec["item"]
    try:
        if rec["object"] is not None:
            t = time.perf_counter()
            kind = OBJECT_KINDS[rec["object"]["kind"]]
            kind.write(tmp / MESH_NAME, rec["object"]["params"])
            times["mesh_time_s"] = time.perf_counter() - t
        capture = tmp / CAPTURE_NAME
        ideal = capture / "ideal" if rec["detector"] is not None else capture
        ideal.parent.mkdir(parents=True, exist_ok=True)
        with resolver_first(tmp):
            job = prepare_render(scene_file, ideal, defines=rec["defines"], spp=rec["spp"], seed=rec["render_seed"],
                                 variant=rec["variant"], noise_target=_noise_target(rec))
        t = time.perf_counter()
        run_render(job, progress=False, on_spot=_kill_hook(rec["index"], tmp))
        times["render_time_s"] = time.perf_counter() - t
        ideal = job.ideal_dir  # capture/ideal when the scene's spad_film ran the detector itself
        from transient_core import stack

        render_m = stack.read_manifest(ideal).get("render") or {}
        estimator = render_m.get("estimator", "monte_carlo")
        target = render_m.get("noise_target")
        # the samples a Monte Carlo spot received (the largest over spots with a target); a quadrature capture
        # has none to count
        spp_used = None if estimator == "quadrature" else max(
            [sp["spp"] for sp in (target or {}).get("spots") or [] if sp and "spp" in sp] or [job.spp])
        del job
        if rec["detector"] is not None:
            t = time.perf_counter()
            _detect(ideal, capture, rec["detector"])
            times["detect_time_s"] = time.perf_counter() - t
        counts = ideal != capture
        detector_seed = None
        render_noise = None
        if counts:
            det_m = stack.read_manifest(capture).get("detector") or {}
            detector_seed = det_m.get("seed")
            render_noise = (det_m.get("resolved") or {}).get("render_noise")
    except UserInputError as e:
        raise ItemError(f"{where}: {e}") from None
    _write_json(tmp / PARAMS_NAME, rec)
    result = {
        "item": rec["item"],
        "params_sha256": rec["params_sha256"],
        "spp_used": spp_used,
        "kind": "counts" if counts else "ideal",
        "ideal": ideal.relative_to(tmp).as_posix(),
        "detector_seed": detector_seed,
        # rendering variance / photon variance of the counts (spad_detector.render_noise), None without
        # a detector or without stored variance
        "render_noise_ratio": (render_noise or {}).get("ratio"),
        # which estimator made the capture (transient_nlos_path's estimator: quadrature or monte_carlo)
        "estimator": estimator,
        "noise_target": None if target is None else {"target": target["target"], "met": target.get("met")},
        **times,
        "total_time_s": time.perf_counter() - t_start,
        "worker": _worker_id(),
        "finished_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "files": list_files(tmp),
    }
    _write_json(tmp / RESULT_NAME, result)
    return result


def _noise_target(rec: dict):
    """The item's :class:`transient_mi.noise_target.NoiseTargetSpec` (its detector and budget), or None."""
    if rec.get("noise_target") is None:
        return None
    from spad_detector import DetectorParams
    from transient_mi.noise_target import NoiseTargetSpec

    det = rec["detector"]
    return NoiseTargetSpec(target=rec["noise_target"], params=DetectorParams.from_dict(det["params"]),
                           pulses=det["pulses"], exposure_s=det["exposure_s"])


def _detect(ideal: Path, out: Path, det: dict) -> None:
    """Counts for the item's detector settings (``spad_detector``, imported lazily)."""
    from spad_detector import DetectorParams, detect_stack

    params = DetectorParams.from_dict(det["params"])
    detect_stack(ideal, out, params, pulses=det["pulses"], exposure_s=det["exposure_s"], seed=det["seed"],
                 engine=det["engine"], progress=False, warn=lambda line: None)  # the ratio goes to the index
