"""The peers' side of the benchmarks that run mitransient (``bench_nlos.py``, ``bench_volpath_mitransient.py``).

mitransient lives in its own virtual environment (``~/.cache/transient-mi-bench/mitransient`` by default,
``TRANSIENT_MI_BENCH_VENV`` to move it; created on demand with ``pip install mitransient``, never a dependency
of transient-mi) and runs in a subprocess with ``DRJIT_LIBLLVM_PATH`` pointing at an LLVM >= 17. One copy of
that harness: the interpreter, its environment, and a timed subprocess call.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MT_VERSION = "1.3.1"
MT_VENV = Path(os.environ.get("TRANSIENT_MI_BENCH_VENV", Path.home() / ".cache/transient-mi-bench/mitransient"))


def mitransient_python(mode: str) -> Path | None:
    """Interpreter of mitransient's virtual environment (created when mode == 'install')."""
    py = MT_VENV / "bin" / "python"
    if mode == "skip":
        return None
    check = "import mitsuba as mi; mi.set_variant('llvm_ad_mono'); import mitransient"
    ok = py.exists() and subprocess.run([str(py), "-c", check], capture_output=True,
                                        env=mt_env()).returncode == 0
    if ok:
        return py
    if mode != "install":
        return None
    print(f"[bench] creating {MT_VENV} with mitransient=={MT_VERSION}", file=sys.stderr)
    MT_VENV.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "venv", "--clear", str(MT_VENV)], check=True)
    subprocess.run([str(py), "-m", "pip", "install", "--quiet", f"mitransient=={MT_VERSION}", "numpy"], check=True)
    return py


def llvm_path() -> str | None:
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]
    sys.path.insert(0, str(ROOT))
    from transient_mi._llvm import resolve_llvm

    return resolve_llvm()


def mt_env() -> dict:
    env = dict(os.environ)
    llvm = llvm_path()
    if llvm:
        env["DRJIT_LIBLLVM_PATH"] = llvm
    env.pop("PYTHONPATH", None)
    return env


def run(cmd, env=None) -> float:
    """Run ``cmd``; its wall time in seconds (a failure raises with the end of its stderr)."""
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed:\n{r.stderr[-4000:]}")
    return time.perf_counter() - t0
