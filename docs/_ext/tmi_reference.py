"""Generate the site's reference pages from the code, at every build.

Written into ``docs/_generated/`` (git-ignored) when the builder starts, so that
nothing generated is committed and nothing can drift:

- ``plugins/<name>.rst``: one page per XML plug-in, discovered from the project's
  plug-in registry (:mod:`transient_mi._registry`: every module of ``films``,
  ``sensors``, ``emitters``, ``integrators``, ``shapes`` with a ``PLUGIN``
  line), showing the class docstring (its parameter table) through autodoc;
- ``api/<package>.rst``: the public names of ``recon``, ``spad_detector``,
  ``transient_core`` and ``transient_mi`` (``__all__``, which the lazy packages
  build from their export tables; for ``transient_core``, whose API is its
  modules, each public module's ``__all__`` or the public names it defines);
- ``cli.rst``: every ``transient-mi`` command and option with its help, read from
  the click command that typer builds (:func:`transient_mi.cli.command`);
- ``gallery.md``: every figure in ``docs/img``, captioned with the alt text of the
  page that shows it, linked to that page.

A page is rewritten only when its text changes (Sphinx then rereads only it).
"""

from __future__ import annotations

import importlib
import inspect
import os
import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1]
OUT = DOCS / "_generated"

#: The packages whose Python API the site documents, in the order of the API index.
API_PACKAGES = ("recon", "spad_detector", "transient_core", "transient_mi")

#: Plug-in kinds in the order the plug-in index lists them.
KINDS = ("film", "sensor", "emitter", "integrator", "shape")


def _write(path: Path, text: str) -> None:
    """Write ``text`` if it changed, atomically (two builds at once, as under pytest-xdist, never read half a page)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.is_file() or path.read_text() != text:
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)


def _title(text: str, ch: str = "=") -> str:
    return f"{text}\n{ch * len(text)}\n"


def rst_escape(text: str) -> str:
    """Plain text (a CLI help string) as RST text: inline-markup characters escaped."""
    return re.sub(r"([\\`*_|])", r"\\\1", text)


# ----------------------------------------------------------------------------- plug-ins


def plugins() -> list[tuple[str, str, str, str]]:
    """Every plug-in as ``(kind, name, module, object name)``, from the registry."""
    from transient_mi import _registry

    out = []
    for modname in _registry._plugin_modules():
        mod = importlib.import_module(modname)
        spec = getattr(mod, "PLUGIN", None)
        if spec is not None:
            kind, name, objname = spec
            out.append((kind, name, modname, objname))
    return sorted(out, key=lambda p: (KINDS.index(p[0]) if p[0] in KINDS else len(KINDS), p[1]))


def plugin_pages() -> dict[str, str]:
    pages = {}
    items = plugins()
    index = [_title("XML plug-ins"),
             "The plug-ins ``import transient_mi`` registers with Mitsuba, one page each, generated from the "
             "plug-in's docstring (its parameter table). They are used like Mitsuba's own, from XML or Python "
             "dictionaries; an overview with the camera and NLOS set-ups is in :doc:`../../scenes`.\n",
             ".. list-table::\n   :header-rows: 1\n\n   * - plug-in\n     - kind\n     - summary"]
    toc = [".. toctree::\n   :hidden:\n"]
    for kind, name, modname, objname in items:
        mod = importlib.import_module(modname)
        obj = getattr(mod, objname)
        summary = (inspect.getdoc(obj) or "").split("\n\n")[0].replace("\n", " ")
        directive = "autoclass" if inspect.isclass(obj) else "autofunction"
        pages[f"plugins/{name}.rst"] = "\n".join([
            f".. _plugin-{name}:\n",
            _title(f"{kind} ``{name}``"),
            f"``<{kind} type=\"{name}\">``: class ``{objname}`` in :mod:`{modname}`"
            " (the page is its docstring).\n",
            f".. py:module:: {modname}\n",
            f".. {directive}:: {modname}.{objname}",
            "   :no-members:\n" if directive == "autoclass" else "",
        ])
        index.append(f"   * - :doc:`{name}`\n     - {kind}\n     - {summary}")
        toc.append(f"   {name}")
    pages["plugins/index.rst"] = "\n".join(index) + "\n\n" + "\n".join(toc) + "\n"
    return pages


# ----------------------------------------------------------------------------- Python API


def public_names(modname: str) -> list[str]:
    """``__all__`` of a module (dunder names left out), else the public names it defines itself."""
    mod = importlib.import_module(modname)
    names = getattr(mod, "__all__", None)
    if names is None:
        names = [n for n, v in vars(mod).items()
                 if not n.startswith("_") and getattr(v, "__module__", None) == modname
                 and (inspect.isclass(v) or inspect.isfunction(v))]
    return [n for n in names if not n.startswith("__")]


def _directive(qualname: str, obj) -> str:
    if inspect.isclass(obj):
        if issubclass(obj, BaseException):
            return f".. autoexception:: {qualname}\n"
        return f".. autoclass:: {qualname}\n   :members:\n"
    if callable(obj):
        return f".. autofunction:: {qualname}\n"
    return f".. autodata:: {qualname}\n   :annotation:\n"


def _module_section(modname: str, with_docstring: bool) -> list[str]:
    mod = importlib.import_module(modname)
    out = [f".. automodule:: {modname}\n   :no-members:\n" if with_docstring else
           f".. py:module:: {modname}\n"]
    for n in public_names(modname):
        out.append(_directive(f"{modname}.{n}", getattr(mod, n)))
    return out


def api_pages() -> dict[str, str]:
    pages = {}
    for pkg in API_PACKAGES:
        mod = importlib.import_module(pkg)
        lines = [_title(f"``{pkg}``")]
        if getattr(mod, "__all__", None) is not None:
            lines.append(f"The public names of ``{pkg}`` (its ``__all__``).\n")
            lines += _module_section(pkg, with_docstring=True)
        else:  # a package whose API is its public modules
            subs = sorted(p.stem for p in Path(mod.__file__).parent.glob("*.py") if not p.stem.startswith("_"))
            lines.append(f"``{pkg}``'s API is its public modules: " + ", ".join(f"``{pkg}.{s}``" for s in subs)
                         + ".\n")
            lines.append(f".. automodule:: {pkg}\n   :no-members:\n")
            for s in subs:
                lines.append(_title(f"``{pkg}.{s}``", "-"))
                lines += _module_section(f"{pkg}.{s}", with_docstring=True)
        pages[f"api/{pkg}.rst"] = "\n".join(lines)
    pages["api/index.rst"] = (_title("Python API") + "\nThe public names of each package (``__all__``, or a "
                              "package's public modules), generated from their numpydoc docstrings.\n\n"
                              ".. toctree::\n\n" + "".join(f"   {p}\n" for p in API_PACKAGES))
    return pages


# ----------------------------------------------------------------------------- CLI


def _commands(group, path: tuple[str, ...] = ()):
    """Every leaf command under ``group`` as ``(path, command)``; a group is anything with ``commands``
    (typer builds its commands on its own copy of click, so no ``isinstance`` against ``click``'s classes)."""
    for name in sorted(group.commands):
        cmd = group.commands[name]
        if getattr(cmd, "hidden", False):
            continue
        if getattr(cmd, "commands", None):
            yield from _commands(cmd, path + (name,))
        else:
            yield path + (name,), cmd


def _usage(full: str, cmd) -> str:
    """``transient-mi render [OPTIONS] SCENE``: the arguments by name, upper case, as the help texts say them."""
    words = [full, "[OPTIONS]"]
    for p in cmd.params:
        if p.param_type_name == "argument":
            w = p.name.upper() + ("..." if p.nargs == -1 else "")
            words.append(w if p.required else f"[{w}]")
    return " ".join(words)


def _help_paragraphs(text: str | None) -> list[str]:
    paras = []
    for p in re.split(r"\n\s*\n", (text or "").strip()):
        p = p.replace("\b\n", "").strip()
        if p:
            paras.append(rst_escape(" ".join(line.strip() for line in p.splitlines())))
    return paras


def cli_page() -> dict[str, str]:
    from transient_mi.cli import command

    root = command()
    lines = [_title("Command line: ``transient-mi``"),
             "Generated from the commands themselves (the click commands typer builds), so every command and "
             "option is listed with its own ``--help`` text. A summary with examples: :doc:`../commands`.\n"]
    lines += _help_paragraphs(root.help)
    lines.append("")
    for path, cmd in _commands(root):
        full = "transient-mi " + " ".join(path)
        sub = cmd.context_class(cmd, info_name=full)
        lines.append(f".. _cli-{'-'.join(path)}:\n")
        lines.append(_title(f"``{full}``", "-"))
        lines += [p + "\n" for p in _help_paragraphs(cmd.help)]
        lines.append(f".. code-block:: text\n\n   {_usage(full, cmd)}\n")
        lines.append(f".. program:: {full}\n")
        for param in cmd.params:
            if param.param_type_name == "argument":
                help_text = getattr(param, "help", None) or "(no help text)"
                lines.append(f".. option:: {param.name.upper()}\n")
                lines.append(f"   Argument{'' if param.required else ' (optional)'}. "
                             f"{' '.join(_help_paragraphs(help_text))}\n")
                continue
            rec = param.get_help_record(sub)
            if rec is None:
                continue
            opts, help_text = rec
            lines.append(f".. option:: {opts}\n")
            for p in _help_paragraphs(help_text) or ["(no help text)"]:
                lines.append(f"   {p}\n")
    return {"cli.rst": "\n".join(lines)}


# ----------------------------------------------------------------------------- gallery

_IMAGE = re.compile(r"!\[(?P<alt>[^\]]*)\]\((?P<path>[^)\s]*img/(?P<name>[^)\s/]+\.(?:png|jpg|gif|svg)))\)")


def gallery_page() -> dict[str, str]:
    shown: dict[str, tuple[str, str]] = {}
    for page in [DOCS.parent / "README.md", *sorted(DOCS.glob("*.md"))]:
        for m in _IMAGE.finditer(page.read_text()):
            if m.group("name") not in shown:
                shown[m.group("name")] = (m.group("alt"), page.stem if page.parent == DOCS else "")
    lines = ["# Gallery\n",
             "Every figure in `docs/img/`, as the pages show it (each made by a script from committed data; "
             "the page that shows a figure says how). Generated from the folder, so a new figure appears here.\n"]
    for img in sorted((DOCS / "img").glob("*.png")):
        alt, page = shown.get(img.name, ("", ""))
        caption = alt or img.stem.replace("_", " ")
        where = f" (in [{page}](../{page}.md))" if page else ""
        lines.append(f"## {caption}\n\n![{caption}](../img/{img.name})\n\n`docs/img/{img.name}`{where}\n")
    return {"gallery.md": "\n".join(lines)}


# ----------------------------------------------------------------------------- Sphinx hook


def generate(out: Path = OUT) -> list[Path]:
    pages = {**plugin_pages(), **api_pages(), **cli_page(), **gallery_page()}
    for rel, text in pages.items():
        _write(out / rel, text)
    keep = {out / rel for rel in pages}
    for old in out.rglob("*"):
        if old.is_file() and old not in keep and not old.name.endswith(".tmp"):
            old.unlink(missing_ok=True)  # a plug-in or command that no longer exists
    return sorted(keep)


def _on_builder_inited(app) -> None:
    generate()


def _lookup(dotted: str):
    """The object a dotted name denotes (module, then attributes), or raise LookupError."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except Exception:
            continue
        for a in parts[i:]:
            if hasattr(obj, a):
                obj = getattr(obj, a)
            elif a in getattr(obj, "__annotations__", {}):  # a dataclass field without a default
                obj = (obj, a)
            else:
                raise LookupError(dotted)
        return obj
    raise LookupError(dotted)


def _documented_object(node):
    """The object whose documentation holds ``node`` (the enclosing autodoc entry), or None."""
    from sphinx import addnodes

    parent = node.parent
    while parent is not None and not isinstance(parent, addnodes.desc):
        parent = parent.parent
    if parent is None:
        return None
    sig = next(iter(parent.findall(addnodes.desc_signature)), None)
    if sig is None or not sig.get("fullname"):
        return None
    try:
        return _lookup(f"{sig.get('module')}.{sig['fullname']}" if sig.get("module") else sig["fullname"])
    except Exception:
        return None


def _scopes(mod: str) -> list[str]:
    out = []
    while mod:
        out.append(mod)
        mod = mod.rsplit(".", 1)[0] if "." in mod else ""
    return out


def _candidates(node) -> list[str]:
    """Where a relative target may live: the page's module and class, the module defining the documented
    object (a public alias documents ``recon.reconstruct``, defined in ``recon.pipeline``), their parents."""
    target = node["reftarget"].lstrip(".~")
    out = [target]
    cls = node.get("py:class") or ""
    mods = [node.get("py:module") or ""]
    obj = _documented_object(node)
    if obj is not None:
        defmod = getattr(obj, "__module__", None) or getattr(obj, "__name__", None)
        owner = getattr(obj, "__qualname__", "").rsplit(".", 1)[0] if "." in getattr(obj, "__qualname__", "") \
            else getattr(obj, "__qualname__", "") if isinstance(obj, type) else ""
        if defmod:
            mods.insert(0, defmod)
            if owner:
                out.append(f"{defmod}.{owner}.{target}")
    for mod in mods:
        if mod and cls:
            out.append(f"{mod}.{cls}.{target}")
        out += [f"{s}.{target}" for s in _scopes(mod)]
    return out


def _on_missing_reference(app, env, node, contnode):
    """Resolve a Python reference the py domain did not find.

    Docstrings name objects where they are defined (``recon.grid.make_grid``, ``.coates``,
    ``validate``), the site documents the public names where users import them
    (``recon.make_grid``). A target that is one of those objects links to its public entry;
    a target that exists but is not public (a helper module, a constant) is shown as plain
    code without a link; a target that names nothing that exists stays a warning (a typo).
    """
    if node.get("refdomain") != "py":
        return None
    py = env.domains["py"]
    public = {}
    for name in py.objects:
        try:
            public.setdefault(id(_lookup(name)), name)
        except Exception:
            continue
    for cand in _candidates(node):
        try:
            obj = _lookup(cand)
        except LookupError:
            continue
        except Exception:
            continue
        name = public.get(id(obj))
        if name is not None and not isinstance(obj, (int, float, str, tuple, bool, type(None))):
            return py.resolve_xref(env, node["refdoc"], app.builder, "obj", name, node, contnode)
        return contnode
    # a bare name documented once on the site (a module docstring naming a class of one of its modules)
    target = node["reftarget"].lstrip(".~")
    matches = [n for n in py.objects if n == target or n.endswith("." + target)]
    if len(matches) == 1:
        return py.resolve_xref(env, node["refdoc"], app.builder, "obj", matches[0], node, contnode)
    return None


def setup(app):
    app.connect("builder-inited", _on_builder_inited)
    app.connect("missing-reference", _on_missing_reference)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}
