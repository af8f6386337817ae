"""The package layout's contract (shared/DESIGN.md, "Layout"; docs/layout.md), and no import circles.

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


# --- the module import graph has no cycle -------------------------------------------------------------
#
# Nodes are the project's modules; a package is its ``__init__.py``. An edge A -> B is an import
# statement in A, wherever it is (module level, inside a function, under ``if TYPE_CHECKING``):
#
# - ``import a.b.c`` is an edge to ``a.b.c`` (to its longest prefix that is a project module). The
#   packages ``a`` and ``a.b`` that Python executes on the way are not edges: a package's ``__init__``
#   only runs once, and counting them would make every package whose ``__init__`` imports its
#   submodules a cycle with each of them.
# - ``from a.b import x`` is an edge to ``a.b.x`` when that is a module. Otherwise, when ``a.b`` is a
#   package that re-exports ``x`` from one of its modules (``from .m import x`` in its ``__init__``, or
#   an entry of a lazy export table: a module-level dict of string names to its submodules, as
#   ``transient_core.lazy_exports`` takes), the edge goes to the module that defines ``x``, as if A had
#   imported it from there: a re-export neither hides a dependency nor makes one up. Only a name the
#   ``__init__`` defines itself is an edge to the package.
# - A package's ``__init__`` importing (or lazily exporting) its own modules is an ordinary edge, so a
#   module that needs a name defined in its package's ``__init__`` while that ``__init__`` imports it
#   is a cycle, as it is when Python runs it.
# - Relative imports are resolved against the importing module's package.
# Imports by string (``importlib.import_module`` in the plug-in registry and the command discovery)
# are not import statements and not edges; the lazy export tables are the exception above.


def _project_modules(root: Path, packages) -> dict[str, tuple[Path, bool]]:
    """``{dotted name: (file, is_package)}`` of every module of ``packages`` under ``root``."""
    out = {}
    for package in sorted(packages):
        for f in sorted((root / package).rglob("*.py")):
            parts = list(f.relative_to(root).with_suffix("").parts)
            is_pkg = parts[-1] == "__init__"
            out[".".join(parts[:-1] if is_pkg else parts)] = (f, is_pkg)
    return out


def _absolute(module: str, is_pkg: bool, level: int, target: str | None) -> str:
    """The absolute name of ``from <level dots><target> import ...`` written in ``module``."""
    if level == 0:
        return target or ""
    base = module.split(".") if is_pkg else module.split(".")[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([target] if target else []))


def _longest_module(name: str, mods) -> str | None:
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in mods:
            return ".".join(parts[:n])
    return None


def _package_exports(name: str, tree: ast.Module, mods) -> dict[str, str]:
    """What the package ``name``'s ``__init__`` re-exports: ``{public name: module it comes from}``."""
    out = {}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom):
            src = _absolute(name, True, node.level, node.module)
            if src in mods and src != name:
                for a in node.names:
                    out.setdefault(a.asname or a.name, src)
        elif isinstance(node, ast.Assign) and isinstance(node.value, ast.Dict):
            d = node.value
            if d.keys and all(isinstance(k, ast.Constant) and isinstance(k.value, str) for k in d.keys) \
                    and all(isinstance(v, ast.Constant) and isinstance(v.value, str) for v in d.values) \
                    and all(f"{name}.{v.value}" in mods for v in d.values):
                for k, v in zip(d.keys, d.values):
                    out[k.value] = f"{name}.{v.value}"
    return out


def import_graph(root: Path = ROOT, packages=PROJECT) -> dict[str, dict[str, int]]:
    """``{module: {imported module: line of the first such import}}`` by the rules above."""
    mods = _project_modules(root, packages)
    trees = {m: ast.parse(f.read_text(), filename=str(f)) for m, (f, _) in mods.items()}
    exports = {m: _package_exports(m, trees[m], mods) for m, (_, is_pkg) in mods.items() if is_pkg}

    def resolve(package: str, name: str, seen=()) -> str:
        if f"{package}.{name}" in mods:
            return f"{package}.{name}"
        src = exports.get(package, {}).get(name)
        if src is None or src in seen:
            return package
        if src in exports:  # re-exported from a subpackage: follow it there
            return resolve(src, name, seen + (src,))
        return src

    graph: dict[str, dict[str, int]] = {}
    for m, (_, is_pkg) in mods.items():
        edges = graph.setdefault(m, {})
        # the lazy export table's modules are imports of the package
        for src in exports.get(m, {}).values():
            edges.setdefault(src, 0)
        for node in ast.walk(trees[m]):
            targets = []
            if isinstance(node, ast.Import):
                targets = [_longest_module(a.name, mods) for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                src = _absolute(m, is_pkg, node.level, node.module)
                base = _longest_module(src, mods)
                if base == src and mods[src][1]:
                    targets = [resolve(src, a.name) for a in node.names]
                else:
                    targets = [base]
            for t in targets:
                if t is not None and t != m:
                    edges.setdefault(t, node.lineno)
    return graph


def import_cycles(graph: dict[str, dict[str, int]]) -> list[tuple[list[str], list[str]]]:
    """``(modules, cycle)`` for each group of modules that reach each other (Tarjan): the group, sorted,
    and one shortest cycle ``[a, b, ..., a]`` through its first module."""
    index, low, stack, on, groups = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, {})):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(set(group))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    cycles = []
    for group in groups:
        start = min(group)
        # shortest way back to start inside the group (breadth first)
        prev, frontier, found = {start: None}, [start], None
        while frontier and found is None:
            nxt = []
            for v in frontier:
                for w in sorted(graph[v]):
                    if w == start:
                        found = v
                        break
                    if w in group and w not in prev:
                        prev[w] = v
                        nxt.append(w)
                if found is not None:
                    break
            frontier = nxt
        path, v = [start], found
        while v != start:
            path.insert(1, v)
            v = prev[v]
        cycles.append((sorted(group), path + [start]))
    return sorted(cycles)


def _describe(found, graph, mods) -> str:
    group, cycle = found
    hops = []
    for a, b in zip(cycle, cycle[1:]):
        f = mods[a][0].relative_to(ROOT) if a in mods else a
        line = graph[a][b]
        hops.append(f"{a} -> {b} ({f}:{line})" if line else f"{a} -> {b} (lazy export table)")
    return (f"{len(group)} modules import each other: {', '.join(group)}\n    one cycle: "
            + "\n    ".join(hops))


def test_the_module_import_graph_has_no_cycle():
    """No two modules import each other, directly or round a circle (shared/DESIGN.md, "Layout")."""
    graph = import_graph()
    cycles = import_cycles(graph)
    mods = _project_modules(ROOT, PROJECT)
    assert not cycles, "import cycles (move the shared part down):\n  " + "\n  ".join(
        _describe(c, graph, mods) for c in cycles)


def test_the_cycle_check_follows_lazy_imports_and_re_exports(tmp_path):
    """The rules above on a made-up package: what is a cycle and what is not."""
    def write(rel, text):
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)

    # a facade whose lazy table and eager re-export point down: not a cycle by itself
    write("pkg/__init__.py", "from .base import Base\n_EXPORTS = {'helper': 'tools', 'Thing': 'sub.thing'}\n")
    write("pkg/base.py", "X = 1\n")
    write("pkg/tools.py", "def helper():\n    from pkg import Base  # resolved to pkg.base\n    return Base\n")
    write("pkg/sub/__init__.py", "")
    write("pkg/sub/thing.py", "from .. import helper  # resolved to pkg.tools\n")
    assert import_cycles(import_graph(tmp_path, {"pkg"})) == []
    assert set(import_graph(tmp_path, {"pkg"})["pkg.sub.thing"]) == {"pkg.tools"}

    # a lazy import inside a function closes a circle
    write("pkg/base.py", "def f():\n    from .sub import thing\n")
    [(group, cycle)] = import_cycles(import_graph(tmp_path, {"pkg"}))
    assert group == ["pkg.base", "pkg.sub.thing", "pkg.tools"] and cycle[0] == cycle[-1]

    # a name the package's __init__ defines itself, needed by a module that __init__ exports
    write("pkg/base.py", "X = 1\n")
    write("pkg/__init__.py", "__version__ = '1'\n_EXPORTS = {'helper': 'tools'}\n")
    write("pkg/tools.py", "from . import __version__\n")
    assert import_cycles(import_graph(tmp_path, {"pkg"})) == [(["pkg", "pkg.tools"], ["pkg", "pkg.tools", "pkg"])]
