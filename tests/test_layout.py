"""The package layout's contract (shared/DESIGN.md, "Layout"; docs/layout.md).

``transient_core`` (capture format, units, errors, files) <- ``spad_detector``, ``recon`` <-
``transient_view`` (the viewer), ``transient_mi``; ``transient_cli`` (the command's front door) on
top. Importing the foundation, the detector model, recon or the viewer must not load drjit or
Mitsuba (a user with only measured data uses them), and no lower package imports a higher one.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: what each package may import of the project's packages
ALLOWED = {
    "transient_core": set(),
    "spad_detector": {"transient_core"},
    "recon": {"transient_core", "spad_detector"},
    "transient_view": {"transient_core", "spad_detector", "recon"},
}
PROJECT = {"transient_core", "spad_detector", "recon", "transient_view", "transient_mi", "transient_cli"}


def _imports(path: Path) -> set[str]:
    """Top-level project packages a module imports (anywhere in it, lazy imports included)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out & PROJECT


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_no_lower_package_imports_a_higher_one(package):
    bad = {}
    for f in sorted((ROOT / package).rglob("*.py")):
        extra = _imports(f) - ALLOWED[package] - {package}
        if extra:
            bad[str(f.relative_to(ROOT))] = sorted(extra)
    assert not bad, f"{package} imports packages above it: {bad}"


@pytest.mark.parametrize("code", [
    "import transient_core, transient_core.stack, transient_core.units, transient_core.lock, transient_core.progress",
    "import spad_detector; spad_detector.detect_stack; spad_detector.DetectorParams; spad_detector.coates_correction;"
    " import spad_detector.engines.analytic, spad_detector.render_noise",
    "import recon; recon.load_capture; recon.run; recon.compute_metrics; import recon.io.ytal, recon.io.real",
    "import transient_view.commands, transient_view.app, transient_view.data, transient_view.server, "
    "transient_view.capture_panel, transient_view.detector_panel, transient_view.recon_panel, transient_view.video",
    # the front door runs the viewer's commands without the renderer
    "import transient_cli; transient_cli.main(['view', '/nonexistent-path', '--no-browser'])",
])
def test_mitsuba_free_packages_do_not_load_drjit_or_mitsuba(code):
    """Each in a fresh interpreter: drjit and mitsuba stay out of ``sys.modules``."""
    probe = code + "; import sys; print(sorted(m for m in ('drjit', 'mitsuba') if m in sys.modules))"
    r = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "[]", f"{code!r} loaded {r.stdout.strip()}"


def test_import_transient_mi_registers_the_plugins():
    code = ("import transient_mi, mitsuba as mi; "
            "s = mi.load_dict({'type': 'scene', 'integrator': {'type': 'transient_nlos_path'}}); "
            "print(type(s.integrator()).__name__)")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "TransientNLOSPath"


def test_no_two_modules_share_a_name_across_packages():
    """One name per concern: a module name (other than ``__init__``/``cli``-style entry points) is used once."""
    seen: dict[str, list[str]] = {}
    for package in sorted(PROJECT):
        for f in (ROOT / package).rglob("*.py"):
            if f.name in ("__init__.py", "__main__.py"):
                continue
            seen.setdefault(f.stem.lstrip("_"), []).append(str(f.relative_to(ROOT)))
    allowed = {
        # commands/<name>.py is the CLI face of the module of the same name, by design
    }
    clashes = {k: v for k, v in seen.items()
               if len(v) > 1 and sum("/commands/" not in p and p not in allowed for p in v) > 1}
    assert not clashes, f"module names used for different jobs: {clashes}"


def test_long_modules_say_why():
    """Small modules with one job each: a module over 500 lines states why in its docstring."""
    long = {}
    for package in sorted(PROJECT):
        for f in (ROOT / package).rglob("*.py"):
            text = f.read_text()
            if text.count("\n") > 500:
                doc = ast.get_docstring(ast.parse(text)) or ""
                if "over 500 lines" not in doc:
                    long[str(f.relative_to(ROOT))] = text.count("\n")
    assert not long, f"modules over 500 lines without a reason in their docstring: {long}"
