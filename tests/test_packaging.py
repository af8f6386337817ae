"""Packaging contracts: recon without Mitsuba, LLVM resolution, CLI basics, one version, and the built
distribution (wheel and sdist) working without the repository."""

import ast
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import time
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("transient_core", "spad_detector", "recon", "transient_view", "transient_mi", "transient_cli")


def _py(code: str, **env):
    e = dict(os.environ)
    e.update(env)
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=e, capture_output=True, text=True, timeout=300)


def test_recon_imports_without_mitsuba():
    r = _py("import recon, recon.io, spad_detector.coates, sys; assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules")
    assert r.returncode == 0, r.stderr


def test_llvm_is_resolved_to_17_or_newer():
    r = _py("import transient_mi, drjit as dr; print(dr.detail.llvm_version()[0])")
    assert r.returncode == 0, r.stderr
    assert int(r.stdout.strip().splitlines()[-1]) >= 17


def test_user_llvm_too_old_gives_clear_error(tmp_path):
    bogus = tmp_path / "libLLVM.so"
    bogus.write_bytes(b"not a library")
    r = _py("import transient_mi", DRJIT_LIBLLVM_PATH=str(bogus))
    assert r.returncode != 0
    assert "DRJIT_LIBLLVM_PATH" in r.stderr and "LLVM >= 17" in r.stderr


def test_unknown_variant_env_gives_clear_error():
    r = _py("import transient_mi", TRANSIENT_MI_VARIANT="llvm_ad_nonsense")
    assert r.returncode != 0
    assert "variant='llvm_ad_nonsense'" in r.stderr and "llvm_ad_mono" in r.stderr


# --- one version -----------------------------------------------------------------------------------------


def _pyproject() -> dict:
    tomllib = pytest.importorskip("tomllib")
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_the_version_is_stated_in_one_place():
    """``transient_core.__version__`` is the version: pyproject.toml reads it (setuptools' dynamic version),
    ``recon`` and ``transient_mi`` import it, and no other file of the packages assigns one."""
    py = _pyproject()
    assert "version" not in py["project"] and "version" in py["project"]["dynamic"]
    assert py["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "transient_core.__version__"}
    assigned = []
    for package in PACKAGES:
        for f in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(f.read_text())):
                if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__version__" for t in node.targets):
                    assigned.append(str(f.relative_to(ROOT)))
    assert assigned == ["transient_core/__init__.py"], assigned
    r = _py("import transient_core, recon; assert recon.__version__ is transient_core.__version__; "
            "print(transient_core.__version__)")
    assert r.returncode == 0, r.stderr
    assert re.fullmatch(r"\d+\.\d+\.\d+", r.stdout.strip())
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert f"## {r.stdout.strip()} " in changelog, "CHANGELOG.md has no section for the current version"


def test_every_third_party_import_is_installed_with_the_package():
    """What the packages import is installed by pip with them: a declared dependency (or extra), or a
    requirement of one. The wheel test below reuses this environment's dependencies, so this is what
    would show a missing declaration."""
    from importlib import metadata

    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    py = _pyproject()["project"]
    todo = [(Requirement(r), "") for r in py["dependencies"]]
    todo += [(Requirement(r), "") for reqs in py["optional-dependencies"].values() for r in reqs]
    installed: set[str] = set()
    while todo:  # the declared requirements and, transitively, theirs (with the extras asked for)
        req, extra = todo.pop()
        if req.marker is not None and not req.marker.evaluate({"extra": extra}):
            continue
        name = canonicalize_name(req.name)
        for want in [""] + sorted(req.extras):
            if (name, want) in installed:
                continue
            installed.add((name, want))
            try:
                sub = metadata.requires(req.name) or []
            except metadata.PackageNotFoundError:
                continue
            todo += [(Requirement(s), want) for s in sub]
    names = {n for n, _ in installed}
    dist_of = metadata.packages_distributions()
    missing = {}
    for package in PACKAGES:
        for f in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(f.read_text())):
                mods = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                    [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module else []
                for m in mods:
                    top = m.split(".")[0]
                    if top in sys.stdlib_module_names or top in PACKAGES or top == "__future__":
                        continue
                    dists = {canonicalize_name(d) for d in dist_of.get(top, [top])}
                    if not dists & names:
                        missing.setdefault(top, f"{f.relative_to(ROOT)}:{node.lineno}")
    assert not missing, f"imported but installed by no declared requirement: {missing}"


# --- the built distribution ------------------------------------------------------------------------------


def _source_copy(dest: Path) -> Path:
    """The files of the working tree that git tracks or would track (no .venv, build outputs, caches)."""
    files = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split("\0")
    for rel in filter(None, files):
        src = ROOT / rel
        if not (src.exists() or src.is_symlink()):
            continue  # deleted in the working tree
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dest / rel, follow_symlinks=False)
    return dest


@pytest.mark.slow
def test_the_wheel_works_without_the_repository(tmp_path):
    """``python -m build`` makes an sdist and, from it, a wheel; ``twine check`` passes their metadata; the
    wheel holds the six packages and the scenes and no tests; installed in a new virtual environment and run
    from a directory outside the repository, ``transient-mi render`` of a shipped scene by name, ``detect``,
    ``recon`` and ``view --help`` work, with every package imported from that environment.

    Dependencies: the new environment is created without system site packages and reuses this environment's
    installed dependencies through a path in a ``.pth`` file (a path line only: the ``.pth`` files there, such
    as the editable install of the repository, are not run), so the test stays fast (a full install of
    mitsuba, LLVM, numba, scipy, ... takes minutes more); the test above checks that every import is a
    declared requirement.
    """
    t_start = time.perf_counter()
    from transient_core import __version__

    pytest.importorskip("build")
    pytest.importorskip("twine")
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs a git checkout (the source files are the ones git tracks)")
    src = _source_copy(tmp_path / "src")
    dist = tmp_path / "dist"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}
    r = subprocess.run([sys.executable, "-m", "build", "--outdir", str(dist), str(src)], capture_output=True,
                       text=True, env=env, cwd=tmp_path, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "Building wheel from sdist" in r.stdout + r.stderr, "the wheel is built from the sdist (so the sdist suffices)"
    t_build = time.perf_counter()
    wheel, = dist.glob(f"transient_mi-{__version__}-py3-none-any.whl")
    sdist, = dist.glob(f"transient_mi-{__version__}.tar.gz")
    r = subprocess.run([sys.executable, "-m", "twine", "check", "--strict", str(wheel), str(sdist)],
                       capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr

    scenes = sorted(p.name for p in (ROOT / "transient_mi" / "scenes").glob("*.xml"))
    assert scenes, "no shipped scenes"
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names} == set(PACKAGES) | {f"transient_mi-{__version__}.dist-info"}
    assert sorted(n.rsplit("/", 1)[1] for n in names if n.startswith("transient_mi/scenes/") and n.endswith(".xml")) \
        == scenes
    for package in PACKAGES:
        want = {str(f.relative_to(ROOT)) for f in (ROOT / package).rglob("*.py") if "__pycache__" not in f.parts}
        assert want <= set(names), f"{package} files missing from the wheel: {sorted(want - set(names))[:5]}"
    assert not [n for n in names if "tests/" in n or n.startswith(("bench/", "docs/", "notebooks/"))]
    metadata = zipfile.ZipFile(wheel).read(f"transient_mi-{__version__}.dist-info/METADATA").decode()
    assert f"\nVersion: {__version__}\n" in metadata
    with tarfile.open(sdist) as tar:
        members = {m.name.split("/", 1)[1] for m in tar.getmembers() if "/" in m.name}
    assert {"pyproject.toml", "README.md", "CHANGELOG.md", "PKG-INFO"} <= members
    assert {f"transient_mi/scenes/{s}" for s in scenes} <= members
    assert not [m for m in members if m.startswith("tests/")], "the sdist holds no (partial) test suite"

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
    vpy = venv / "bin" / "python"
    site = Path(subprocess.run([str(vpy), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "_transient_mi_test_deps.pth").write_text("\n".join(sorted(deps)) + "\n")
    r = subprocess.run([sys.executable, "-m", "pip", "--python", str(vpy), "install", "--no-deps", "--no-index",
                        "--ignore-installed", "--quiet", str(wheel)], capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    t_install = time.perf_counter()

    work = tmp_path / "work"
    work.mkdir()
    assert ROOT not in work.resolve().parents
    env = dict(env, TRANSIENT_MI_PROGRESS="0")
    probe = ("import sys, importlib.metadata as md, transient_core, spad_detector, recon, transient_view, transient_mi, "
             "transient_cli; mods = [transient_core, spad_detector, recon, transient_view, transient_mi, transient_cli]; "
             "print(md.version('transient-mi')); print(*[m.__file__ for m in mods], sep='\\n'); print(*sys.path, sep='\\n')")
    r = subprocess.run([str(vpy), "-c", probe], capture_output=True, text=True, env=env, cwd=work, timeout=300)
    assert r.returncode == 0, r.stderr
    version, *lines = r.stdout.strip().splitlines()
    assert version == __version__
    files, path = lines[:len(PACKAGES)], lines[len(PACKAGES):]
    assert all(Path(f).is_relative_to(site) for f in files), files
    # the repository is not on the path (its venv's site-packages may be inside it: the dependencies' path)
    assert not [p for p in path if p and Path(p).resolve().is_relative_to(ROOT) and p not in deps], path

    cli = venv / "bin" / "transient-mi"

    def run(*args):
        r = subprocess.run([str(cli), *map(str, args)], capture_output=True, text=True, env=env, cwd=work,
                           timeout=600)
        assert r.returncode == 0, f"transient-mi {' '.join(map(str, args))}:\n{r.stdout[-2000:]}{r.stderr[-2000:]}"
        return r.stdout

    small = ["-D", "width=4", "-D", "height=4", "-D", "spots_x=1", "-D", "spots_y=1", "-D", "n_bins=64",
             "-D", "bin_width_ps=64"]
    assert "wrote cap" in run("render", "nlos_point_targets", "-o", "cap", "--spp", 4, *small)
    scene_file = Path(json.loads((work / "cap" / "manifest.json").read_text())["render"]["scene_file"])
    assert scene_file.is_relative_to(site) and scene_file.name == "nlos_point_targets.xml"
    run("detect", "cap", "-o", "counts", "--seed", 1)
    run("recon", "counts", "-o", "rec", "--voxels", 8)
    assert (work / "rec" / "volume.npz").is_file()
    assert "Usage" in run("view", "--help")
    t_end = time.perf_counter()
    print(f"wheel test: build {t_build - t_start:.0f} s, install {t_install - t_build:.0f} s, "
          f"commands {t_end - t_install:.0f} s, total {t_end - t_start:.0f} s")
