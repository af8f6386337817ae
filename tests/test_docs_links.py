"""The Markdown pages as a reader follows them: every relative link resolves, every Python block runs or says why not.

Covers README.md and docs/*.md (what GitHub shows, and the pages of the documentation site). Links to
`page.md#anchor` must name a heading of that page (GitHub's and MyST's anchor: lower case, punctuation
dropped, spaces as hyphens). A ```python block is run here, in a temporary directory, unless the line
before it is ``<!-- not executed: REASON -->``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^(```|~~~).*?^\1\s*$", re.S | re.M)
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
PYTHON = re.compile(r"(?P<before>[^\n]*)\n```python\n(?P<code>.*?)```", re.S)
NOT_EXECUTED = re.compile(r"<!-- not executed: \S.*-->")


def _prose(text: str) -> str:
    """The page without fenced code blocks and inline code (links there are examples, not links)."""
    return re.sub(r"`[^`\n]*`", "", FENCE.sub("", text))


def slug(heading: str) -> str:
    """GitHub's anchor for a heading (MyST's ``myst_heading_anchors`` makes the same)."""
    text = re.sub(r"`([^`]*)`", r"\1", heading.strip().lower())
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    out: set[str] = set()
    for line in FENCE.sub("", page.read_text()).splitlines():
        m = re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            s, n = slug(m.group(1)), 1
            while s in out:  # repeated headings get -1, -2, ...
                s = f"{slug(m.group(1))}-{n}"
                n += 1
            out.add(s)
    return out


def links(page: Path) -> list[str]:
    return [m.group(1) for m in LINK.finditer(_prose(page.read_text()))]


def test_every_docs_page_is_in_the_site_index():
    """A new docs/*.md page must be listed in a toctree of docs/index.md (the site build fails otherwise too)."""
    index = (ROOT / "docs" / "index.md").read_text()
    listed = {line.strip() for block in re.findall(r"```\{toctree\}\n(.*?)```", index, re.S)
              for line in block.splitlines() if line.strip() and not line.startswith(":")}
    pages = {p.stem for p in (ROOT / "docs").glob("*.md")} - {"index"}
    assert not pages - listed, f"add to a toctree in docs/index.md: {sorted(pages - listed)}"
    assert not {x for x in listed - pages if not x.startswith("_generated/")}, listed - pages


def test_the_link_finder_finds_links():
    page = ROOT / "README.md"
    found = links(page)
    assert "docs/getting_started.md" in found and "docs/img/detector_effects.png" in found
    assert slug("Closing the surface behind the front (`recon.completion`): a prior, not a measurement") == \
        "closing-the-surface-behind-the-front-reconcompletion-a-prior-not-a-measurement"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    bad = []
    for target in links(page):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = unquote(target).partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{target}: no heading with anchor #{anchor} in {dest.relative_to(ROOT)}")
    assert not bad, f"{page.relative_to(ROOT)}: " + "; ".join(bad)


def _python_blocks():
    for page in PAGES:
        text = page.read_text()
        for m in PYTHON.finditer(text):
            line = text[:m.start("code")].count("\n")
            yield pytest.param(page, m.group("before"), m.group("code"), id=f"{page.relative_to(ROOT)}:{line}")


@pytest.mark.parametrize("page, before, code", list(_python_blocks()))
def test_every_python_block_runs_or_says_why_not(page, before, code, tmp_path):
    if NOT_EXECUTED.search(before):
        return
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0", PYTHONPATH=str(ROOT))
    (tmp_path / "scenes").symlink_to(ROOT / "scenes")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, (f"{page.relative_to(ROOT)}: a python block failed (mark it "
                               f"'<!-- not executed: REASON -->' if it cannot run here):\n{r.stderr}")


def test_getting_started_runs_as_written(tmp_path):
    """The first render, detection and reconstruction of docs/getting_started.md, command by command."""
    import json
    import shlex

    text = (ROOT / "docs" / "getting_started.md").read_text()
    commands = [shlex.split(line.split("#", 1)[0]) for block in re.findall(r"```bash\n(.*?)```", text, re.S)
                for line in block.splitlines() if line.startswith("transient-mi ")]
    assert [c[1] for c in commands] == ["render", "detect", "scene-mesh", "recon"], commands
    (tmp_path / "scenes").symlink_to(ROOT / "scenes")
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    for cmd in commands:
        r = subprocess.run([sys.executable, "-m", "transient_mi", *cmd[1:]], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, (cmd, r.stderr)
    metrics = json.loads((tmp_path / "out" / "letter_recon" / "metrics.json").read_text())
    assert metrics["depth_mae_m"] < 0.01 and metrics["iou"] > 0.5, metrics  # the F (IoU 0.74 when written)
    assert (tmp_path / "out" / "letter_counts" / "manifest.json").is_file()


def test_some_python_block_is_executed():
    assert any(not NOT_EXECUTED.search(b.values[1]) for b in _python_blocks())
