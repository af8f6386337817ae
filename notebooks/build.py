"""Build the notebooks from their sources and execute them, embedding the outputs.

The sources are plain Python scripts in the "percent" format (``notebooks/src/NN_name.py``;
jupytext and VS Code read it too): ``# %%`` starts a code cell, ``# %% [markdown]`` a
markdown cell whose lines are written as comments (``# text``), ``# %% [setup]`` the
setup cell every notebook shares (``src/_setup_cell.py``, written once). This script turns each
into ``notebooks/NN_name.ipynb`` and runs it in a Jupyter kernel started from the
Python interpreter that runs this script (not whatever ``python`` is first on PATH).

Usage (from the repository root or from notebooks/)::

    python notebooks/build.py                  # every notebook, full settings, outputs embedded
    python notebooks/build.py 01 04            # only the notebooks whose names start with 01 or 04
    python notebooks/build.py --small -o /tmp/nb  # tiny settings (what the tests run), elsewhere
    python notebooks/build.py --no-execute     # convert only (no outputs)

Notebooks run with ``notebooks/`` as the working directory and write their data under
``out/notebooks/`` (or ``$TRANSIENT_MI_NOTEBOOK_OUT``); ``--small`` sets
``TRANSIENT_MI_NOTEBOOK_SMALL=1``. A notebook is written under a temporary name and renamed,
so a failed run leaves the previous file in place. ``tests/test_notebooks.py`` uses
:func:`notebook_from_source` and :func:`execute_notebook`.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import nbformat

HERE = Path(__file__).resolve().parent
SRC = HERE / "src"
KERNEL_NAME = "transient-mi-notebooks"
#: Embedded in the notebooks' metadata (what Jupyter and GitHub show and use to open them).
KERNELSPEC = {"name": "python3", "display_name": "Python 3 (ipykernel)", "language": "python"}

#: The text of every notebook's ``# %% [setup]`` cell (its leading comment block dropped), with
#: ``__NOTEBOOK__`` replaced by the notebook's name.
SETUP_CELL = SRC / "_setup_cell.py"
_MARKER = re.compile(r"^# %%(?P<title>[^\[]*)(\[(?P<kind>\w+)\])?\s*$")


def sources(patterns=()) -> list[Path]:
    """The notebook sources ``notebooks/src/NN_*.py``, in order; only names starting with a pattern, if given."""
    found = sorted(SRC.glob("[0-9][0-9]_*.py"))
    if patterns:
        found = [p for p in found if any(p.stem.startswith(q) for q in patterns)]
    return found


def _markdown(lines: list[str], path: Path, lineno: int) -> str:
    out = []
    for i, line in enumerate(lines):
        if line.strip() == "":
            out.append("")
        elif line == "#":
            out.append("")
        elif line.startswith("# "):
            out.append(line[2:])
        else:
            raise ValueError(f"{path}:{lineno + i + 1}: a markdown cell line must start with '# ' (got {line!r})")
    return "\n".join(out).strip("\n")


def setup_cell(name: str) -> str:
    """The shared first code cell (``SETUP_CELL``) for the notebook ``name`` (e.g. ``01_quickstart``)."""
    lines = SETUP_CELL.read_text(encoding="utf-8").splitlines()
    while lines and lines[0].startswith("#"):
        lines.pop(0)
    return "\n".join(lines).strip("\n").replace("__NOTEBOOK__", name)


def notebook_from_source(path) -> nbformat.NotebookNode:
    """Parse a percent-format script into a notebook (no outputs).

    ``# %% [setup]`` stands for the shared setup cell (:func:`setup_cell`); what follows it up to
    the next marker must be blank.

    Raises
    ------
    ValueError
        If the file has text before its first ``# %%`` marker (other than
        blank lines), an unknown cell kind, or a malformed markdown cell.
    """
    path = Path(path)
    lines = path.read_text(encoding="utf-8").splitlines()
    cells: list[tuple[str, int, list[str]]] = []
    for i, line in enumerate(lines):
        m = _MARKER.match(line)
        if m:
            kind = m.group("kind") or "code"
            if kind not in ("code", "markdown", "md", "setup"):
                raise ValueError(f"{path}:{i + 1}: unknown cell kind [{kind}] (use [markdown], [setup] or nothing)")
            cells.append(("markdown" if kind in ("markdown", "md") else kind, i + 1, []))
        elif cells:
            cells[-1][2].append(line)
        elif line.strip():
            raise ValueError(f"{path}:{i + 1}: text before the first '# %%' cell marker")
    nb = nbformat.v4.new_notebook()
    for kind, lineno, body in cells:
        if kind == "markdown":
            text = _markdown(body, path, lineno)
            if text:
                nb.cells.append(nbformat.v4.new_markdown_cell(text))
        elif kind == "setup":
            if any(line.strip() for line in body):
                raise ValueError(f"{path}:{lineno}: a [setup] cell takes no text (it is {SETUP_CELL.name})")
            nb.cells.append(nbformat.v4.new_code_cell(setup_cell(path.stem)))
        else:
            text = "\n".join(body).strip("\n")
            if text:
                nb.cells.append(nbformat.v4.new_code_cell(text))
    for k, cell in enumerate(nb.cells):  # stable ids: diffs of rebuilt notebooks stay small
        cell["id"] = f"{path.stem[:2]}-{k:03d}"
    nb.metadata["kernelspec"] = dict(KERNELSPEC)
    nb.metadata["language_info"] = {"name": "python"}
    return nb


@contextmanager
def kernel_manager():
    """A ``KernelManager`` whose kernel is ``sys.executable -m ipykernel_launcher``.

    The kernel spec lives in a temporary directory, so the kernel runs in the
    environment of the interpreter running this code (the ``python3`` spec that
    ipykernel installs runs ``python``, which may be another interpreter).
    """
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import KernelManager

    with tempfile.TemporaryDirectory(prefix="transient-mi-kernel-") as tmp:
        d = Path(tmp) / KERNEL_NAME
        d.mkdir()
        spec = {"argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
                "display_name": f"Python ({sys.executable})", "language": "python",
                "metadata": {"debugger": False}}
        (d / "kernel.json").write_text(json.dumps(spec))
        ksm = KernelSpecManager(kernel_dirs=[tmp])
        yield KernelManager(kernel_name=KERNEL_NAME, kernel_spec_manager=ksm)


def kernel_env(*, small: bool, out_dir=None) -> dict:
    """Environment of the kernel: ours, plus the notebook switches; no ``MPLBACKEND`` (inline plots)."""
    env = dict(os.environ)
    env.pop("MPLBACKEND", None)
    env["TRANSIENT_MI_PROGRESS"] = "0"
    env["PYDEVD_DISABLE_FILE_VALIDATION"] = "1"
    if small:
        env["TRANSIENT_MI_NOTEBOOK_SMALL"] = "1"
    else:
        env.pop("TRANSIENT_MI_NOTEBOOK_SMALL", None)
    if out_dir is not None:
        env["TRANSIENT_MI_NOTEBOOK_OUT"] = str(out_dir)
    return env


def execute_notebook(nb, *, cwd=HERE, small: bool = False, out_dir=None, timeout_s: float = 1800.0):
    """Run every cell of ``nb`` (in place) in a fresh kernel; returns ``nb``.

    The kernel is driven from a child process (``build.py --execute-one``) that is killed, kernel
    included, once ``timeout_s`` plus a grace of :data:`GRACE_S` has passed: a kernel that dies in
    native code (a segmentation fault in a Dr.Jit worker thread, say) can leave nbclient waiting
    for output that never comes, and a test must fail, not hang.

    Parameters
    ----------
    nb : nbformat.NotebookNode
    cwd : path
        Working directory of the kernel.
    small : bool
        Set ``TRANSIENT_MI_NOTEBOOK_SMALL=1`` (tiny renders).
    out_dir : path, optional
        ``TRANSIENT_MI_NOTEBOOK_OUT``: where the notebook writes its data.
    timeout_s : float
        Wall-clock limit for the whole notebook, seconds (each cell gets what is left).

    Raises
    ------
    NotebookError
        A cell raised, the kernel died, or the notebook ran past ``timeout_s`` (the message says
        which, with the end of the child's output).
    """
    with tempfile.TemporaryDirectory(prefix="transient-mi-nb-") as tmp:
        src, dst = Path(tmp) / "in.ipynb", Path(tmp) / "out.ipynb"
        nbformat.write(nb, str(src))
        cmd = [sys.executable, str(Path(__file__).resolve()), "--execute-one", str(src), str(dst),
               "--cwd", str(cwd), "--timeout", str(timeout_s)]
        if small:
            cmd.append("--small")
        if out_dir is not None:
            cmd += ["--out-dir", str(out_dir)]
        log = Path(tmp) / "log.txt"
        with open(log, "wb") as f:
            proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
            try:
                rc = proc.wait(timeout=timeout_s + GRACE_S)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                rc = None
        tail = log.read_text(errors="replace")[-4000:]
        if rc is None:
            raise NotebookError(f"the notebook ran past {timeout_s:.0f} s (+{GRACE_S:.0f} s grace) and was "
                                f"killed; its kernel hung or died. Output:\n{tail}")
        if rc != 0:
            raise NotebookError(f"executing the notebook failed (exit status {rc}):\n{tail}")
        done = nbformat.read(str(dst), as_version=4)
    nb.cells = done.cells
    nb.metadata = done.metadata
    return nb


class NotebookError(RuntimeError):
    """A notebook did not run to its end: a cell raised, its kernel died, or it ran out of time."""


#: Seconds the child driving the kernel gets past the notebook's own limit before it is killed.
GRACE_S = 60.0


def _execute_in_this_process(nb, *, cwd, small: bool, out_dir, timeout_s: float):
    """What :func:`execute_notebook`'s child runs: nbclient in this process (cell errors raise)."""
    from nbclient import NotebookClient

    deadline = time.monotonic() + timeout_s

    def remaining(cell):
        return max(1, int(deadline - time.monotonic()))

    with kernel_manager() as km:
        shutdown = km.shutdown_kernel

        def shutdown_kernel(*args, **kwargs):  # (nbclient's own shutdown: the watchdog stands down)
            km._transient_mi_shutting_down = True
            return shutdown(*args, **kwargs)

        km.shutdown_kernel = shutdown_kernel
        threading.Thread(target=_exit_when_kernel_dies, args=(km,), daemon=True).start()
        client = NotebookClient(nb, km=km, timeout_func=remaining, record_timing=False, allow_errors=False,
                                resources={"metadata": {"path": str(cwd)}})
        client.execute(env=kernel_env(small=small, out_dir=out_dir))
    nb.metadata["kernelspec"] = dict(KERNELSPEC)
    return nb


def _exit_when_kernel_dies(km, poll_s: float = 0.5) -> None:
    """Watchdog thread of :func:`_execute_in_this_process`: exit this process (status 3) once the kernel
    process has ended on its own. nbclient 0.11 waits forever for the output of a cell whose kernel died
    of a signal (measured: a segmentation fault in a cell)."""
    while True:
        time.sleep(poll_s)
        proc = getattr(getattr(km, "provisioner", None), "process", None)
        code = proc.poll() if proc is not None else None
        if code is not None and not getattr(km, "_transient_mi_shutting_down", False):
            print(f"the notebook's kernel died (exit status {code}"
                  f"{', signal ' + signal.Signals(-code).name if code < 0 else ''})", file=sys.stderr, flush=True)
            os._exit(3)


def _execute_one(argv) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--cwd", required=True)
    ap.add_argument("--timeout", type=float, required=True)
    ap.add_argument("--small", action="store_true")
    ap.add_argument("--out-dir", default=None)
    a = ap.parse_args(argv)
    nb = nbformat.read(a.src, as_version=4)
    _execute_in_this_process(nb, cwd=a.cwd, small=a.small, out_dir=a.out_dir, timeout_s=a.timeout)
    nbformat.write(nb, a.dst)
    return 0


def image_outputs(nb) -> int:
    """Number of image outputs (PNG, GIF, JPEG, SVG) in ``nb``, including images embedded in HTML."""
    n = 0
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            data = out.get("data", {})
            n += sum(1 for k in data if k.startswith("image/"))
            n += str(data.get("text/html", "")).count("data:image/")
    return n


def write_notebook(nb, path) -> Path:
    """Write ``nb`` to ``path`` atomically (temporary name in the same folder, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            nbformat.write(nb, f)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["--execute-one"]:  # (execute_notebook's child)
        return _execute_one(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="*", help="build only notebooks whose names start with these (e.g. 01 03)")
    ap.add_argument("--small", action="store_true", help="tiny settings (TRANSIENT_MI_NOTEBOOK_SMALL=1)")
    ap.add_argument("--no-execute", action="store_true", help="convert only; the notebooks get no outputs")
    ap.add_argument("-o", "--out", default=str(HERE), help="where to write the .ipynb files (default notebooks/)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per notebook (default 1800)")
    args = ap.parse_args(argv)
    srcs = sources(args.names)
    if not srcs:
        print(f"error: no notebook source in {SRC} matches {args.names}", file=sys.stderr)
        return 2
    out = Path(args.out)
    if args.small and out.resolve() == HERE:
        print("error: --small would overwrite the committed notebooks; give -o DIR", file=sys.stderr)
        return 2
    for src in srcs:
        nb = notebook_from_source(src)
        t0 = time.perf_counter()
        if not args.no_execute:
            execute_notebook(nb, small=args.small, timeout_s=args.timeout)
        target = write_notebook(nb, out / f"{src.stem}.ipynb")
        size = target.stat().st_size
        print(f"{target}: {len(nb.cells)} cells, {image_outputs(nb)} images, {size / 1e6:.2f} MB, "
              f"{time.perf_counter() - t0:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
