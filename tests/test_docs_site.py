"""The documentation site builds without a warning and covers every plug-in, command, public name and page.

Builds with ``sphinx-build -b html -W --keep-going -n`` (what ``bash run.sh docs`` runs) into a
temporary directory. The reference pages are generated at the build from the plug-in registry, the
click commands and ``__all__`` (``docs/_ext/tmi_reference.py``), so a new plug-in, command or public
name must appear without anyone editing a page; this test checks that they do.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    import importlib.util
    import os

    if importlib.util.find_spec("sphinx") is None:
        why = "the docs extra is not installed: pip install -e '.[docs]' (bash run.sh test installs it)"
        if os.environ.get("CI"):
            pytest.fail(why)  # CI installs it: a skip there would hide a broken install
        pytest.skip(why)
    out = tmp_path_factory.mktemp("site")
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-n", "-q",
                        "-d", str(out / "doctrees"), str(DOCS), str(out / "html")],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    return r, out / "html", time.perf_counter() - t


def test_the_site_builds_without_warnings(site):
    r, html, seconds = site
    assert r.returncode == 0, r.stdout + r.stderr
    assert "WARNING" not in r.stderr and "ERROR" not in r.stderr, r.stderr
    assert (html / "index.html").is_file()
    print(f"site built in {seconds:.0f} s")


def test_every_page_of_docs_is_on_the_site(site):
    _, html, _ = site
    for page in DOCS.glob("*.md"):
        assert (html / f"{page.stem}.html").is_file(), page.name


def test_every_plugin_has_its_reference_page(site):
    import transient_mi

    _, html, _ = site
    names = transient_mi.plugin_names()
    assert {"transient_film", "spad_film", "transient_path", "transient_nlos_path", "transient_volpath",
            "spad_array", "pulsed_laser", "mannequin"} <= set(names)
    for name in names:
        page = html / "_generated" / "plugins" / f"{name}.html"
        assert page.is_file(), name
    text = (html / "_generated" / "plugins" / "spad_array.html").read_text()
    assert "<table" in text and "pixel_footprint_m" in text  # the docstring's parameter table


def test_every_command_and_option_is_in_the_cli_reference(site):
    from transient_mi.cli import command

    _, html, _ = site
    text = (html / "_generated" / "cli.html").read_text()

    def walk(group, path=()):  # typer's commands are built on its own copy of click: no isinstance
        for name, cmd in group.commands.items():
            if getattr(cmd, "commands", None):
                yield from walk(cmd, path + (name,))
            elif not cmd.hidden:
                yield path + (name,), cmd

    commands = list(walk(command()))
    assert {("render",), ("detect",), ("recon",), ("study", "methods"), ("view",)} <= {p for p, _ in commands}
    for path, cmd in commands:
        assert f'id="cli-{"-".join(path)}"' in text, path
        for p in cmd.params:
            if p.param_type_name == "option" and not p.hidden:
                assert p.opts[-1] in text, (path, p.opts)
            elif p.param_type_name == "argument":
                assert p.name.upper() in text, (path, p.name)


def test_the_public_api_is_documented(site):
    import recon
    import spad_detector
    import transient_mi

    _, html, _ = site
    for pkg in (recon, spad_detector, transient_mi):
        text = (html / "_generated" / "api" / f"{pkg.__name__}.html").read_text()
        for name in pkg.__all__:
            if not name.startswith("__"):
                assert re.search(rf'id="{re.escape(pkg.__name__)}\.{re.escape(name)}"', text), (pkg.__name__, name)
    core = (html / "_generated" / "api" / "transient_core.html").read_text()
    assert 'id="transient_core.stack.read_stack"' in core


def test_the_gallery_shows_every_figure(site):
    _, html, _ = site
    text = (html / "_generated" / "gallery.html").read_text()
    for img in (DOCS / "img").glob("*.png"):
        assert img.name in text, img.name
