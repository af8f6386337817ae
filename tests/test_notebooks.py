"""The notebooks: each runs without errors on small settings and shows pictures.

Every notebook in ``notebooks/src/`` is converted (``notebooks/build.py``) and executed with
``TRANSIENT_MI_NOTEBOOK_SMALL=1`` in a Jupyter kernel started from this interpreter, with
``notebooks/`` as its working directory and its data written under a temporary directory.
The committed ``notebooks/*.ipynb`` must be built from the current sources, executed, and small.
"""

from __future__ import annotations

import importlib.util
import sys
import time
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"
#: Wall-clock limit per notebook on small settings, seconds (they take ~3-10 s on 2 cores).
TIMEOUT_S = 300
#: Largest committed notebook, bytes (outputs included).
MAX_IPYNB_BYTES = 1_500_000


def _load_build():
    spec = importlib.util.spec_from_file_location("notebooks_build", NOTEBOOKS / "build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


build = _load_build()
SOURCES = build.sources()


def _errors(nb) -> list[str]:
    return [f"{o.get('ename')}: {o.get('evalue')}" for c in nb.cells for o in c.get("outputs", [])
            if o.get("output_type") == "error"]


def test_every_notebook_has_a_source():
    names = [p.stem for p in SOURCES]
    assert names == ["01_quickstart", "02_nlos_capture", "03_detector_model", "04_reconstruction_methods",
                     "05_photon_budget", "06_inverse_nlos"]


@pytest.mark.parametrize("src", SOURCES, ids=[p.stem for p in SOURCES])
def test_notebook_runs_on_small_settings_and_shows_pictures(src, tmp_path):
    nb = build.notebook_from_source(src)
    build.execute_notebook(nb, cwd=NOTEBOOKS, small=True, out_dir=tmp_path, timeout_s=TIMEOUT_S)
    assert _errors(nb) == []
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(c.execution_count is not None for c in code), "a code cell did not run"
    assert build.image_outputs(nb) >= 1
    # its data went to the directory it was given, not into the repository
    assert any((tmp_path / src.stem).iterdir())
    assert not list(NOTEBOOKS.glob("**/*.exr"))


def test_notebook_runs_from_the_repository_root(tmp_path):
    nb = build.notebook_from_source(SOURCES[0])
    build.execute_notebook(nb, cwd=ROOT, small=True, out_dir=tmp_path, timeout_s=TIMEOUT_S)
    assert _errors(nb) == [] and build.image_outputs(nb) >= 1


def test_kernel_is_this_interpreter():
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell("import sys, os; print(sys.executable); "
                                          "print(os.environ.get('TRANSIENT_MI_NOTEBOOK_SMALL'))")]
    build.execute_notebook(nb, small=True, timeout_s=120)
    lines = nb.cells[0].outputs[0]["text"].split()
    assert Path(lines[0]).resolve() == Path(sys.executable).resolve()
    assert lines[1] == "1"


def test_a_kernel_that_dies_in_native_code_fails_the_notebook_instead_of_hanging():
    # (a Dr.Jit worker thread once segfaulted in a test run and nbclient waited for output forever)
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell("import ctypes; ctypes.string_at(0)"),
                nbformat.v4.new_code_cell("print('never')")]
    t0 = time.monotonic()
    with pytest.raises(build.NotebookError, match="kernel died .*SIGSEGV"):
        build.execute_notebook(nb, small=True, timeout_s=120)
    assert time.monotonic() - t0 < 60  # (it took 180 s, killed by the grace, before the watchdog)


def test_a_notebook_past_its_time_is_stopped(monkeypatch):
    monkeypatch.setattr(build, "GRACE_S", 5.0)
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell("import time; time.sleep(600)")]
    t0 = time.monotonic()
    with pytest.raises(build.NotebookError):
        build.execute_notebook(nb, small=True, timeout_s=3)
    assert time.monotonic() - t0 < 3 + 5 + 10  # (the limit, the grace and a margin for the kill)


@pytest.mark.parametrize("src", SOURCES, ids=[p.stem for p in SOURCES])
def test_committed_notebook_is_built_from_its_source(src):
    path = NOTEBOOKS / f"{src.stem}.ipynb"
    assert path.is_file(), f"{path.name} missing: run python notebooks/build.py {src.stem[:2]}"
    committed = nbformat.read(path, as_version=4)
    fresh = build.notebook_from_source(src)
    assert [(c.cell_type, c.source) for c in committed.cells] == [(c.cell_type, c.source) for c in fresh.cells], \
        f"{path.name} is out of date with {src.relative_to(ROOT)}: run python notebooks/build.py {src.stem[:2]}"
    assert all(c.execution_count is not None for c in committed.cells if c.cell_type == "code"), \
        f"{path.name} was not executed"
    assert _errors(committed) == []
    assert build.image_outputs(committed) >= 1
    assert path.stat().st_size <= MAX_IPYNB_BYTES


def test_percent_format_parser(tmp_path):
    src = tmp_path / "99_x.py"
    src.write_text("# %% [markdown]\n# # Title\n#\n# text with `code`\n\n# %%\nx = 1\n\n\n# %%\nprint(x)\n")
    nb = build.notebook_from_source(src)
    assert [(c.cell_type, c.source) for c in nb.cells] == [
        ("markdown", "# Title\n\ntext with `code`"), ("code", "x = 1"), ("code", "print(x)")]
    setup = tmp_path / "97_setup.py"
    setup.write_text("# %% [setup]\n\n# %%\nprint(OUT)\n")
    nb = build.notebook_from_source(setup)
    assert [(c.cell_type, c.source) for c in nb.cells] == [("code", build.setup_cell("97_setup")), ("code", "print(OUT)")]
    assert '/ "97_setup"' in nb.cells[0].source and "__NOTEBOOK__" not in nb.cells[0].source
    assert not nb.cells[0].source.startswith("#")  # the template's header comment is not part of the cell
    setup.write_text("# %% [setup]\nx = 1\n")
    with pytest.raises(ValueError, match="takes no text"):
        build.notebook_from_source(setup)
    bad = tmp_path / "98_bad.py"
    bad.write_text("import os\n# %%\nx = 1\n")
    with pytest.raises(ValueError, match="before the first"):
        build.notebook_from_source(bad)
    bad.write_text("# %% [markdown]\nnot a comment\n")
    with pytest.raises(ValueError, match="must start with '# '"):
        build.notebook_from_source(bad)
