"""Example scenes shipped with transient-mi (XML files in this folder).

The repository's top-level ``scenes/`` is a link to this package folder, so
the files are both easy to find in a clone and installed with the package.
"""

from __future__ import annotations

from pathlib import Path

SCENES_DIR = Path(__file__).resolve().parent


def scene_path(name: str) -> Path:
    """Path of a shipped scene, by file name (``"cornell_box.xml"``) or stem."""
    p = SCENES_DIR / (name if name.endswith(".xml") else f"{name}.xml")
    if not p.is_file():
        from transient_core.errors import UserInputError

        avail = ", ".join(sorted(q.stem for q in SCENES_DIR.glob("*.xml")))
        raise UserInputError(f"scene {name!r} is not shipped with transient-mi; available: {avail}")
    return p


def shipped_scene(name) -> Path | None:
    """The shipped scene called ``name`` (``"cornell_box"`` or ``"cornell_box.xml"``, no directory part), or
    None: how ``transient-mi render`` and the studies take a scene by name from an installed package."""
    name = str(name)
    if not name.strip() or "/" in name or "\\" in name:
        return None
    p = SCENES_DIR / (name if name.endswith(".xml") else f"{name}.xml")
    return p if p.is_file() else None
