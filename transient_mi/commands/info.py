"""``transient-mi info``: versions, variant, LLVM and registered plug-ins."""

from __future__ import annotations

import typer


def info(variant: str = typer.Option(None, "--variant", help="Mitsuba variant to select first.")) -> None:
    """Print versions, the Mitsuba variant, the LLVM in use, the plug-ins and the shipped scenes."""
    import drjit as dr
    import mitsuba as mi

    import transient_mi as tm

    if variant:
        tm.set_variant(variant)
    llvm = dr.detail.llvm_version()
    typer.echo(f"transient-mi {tm.__version__}")
    typer.echo(f"mitsuba {mi.__version__}, drjit {dr.__version__}")
    typer.echo(f"variant {tm.variant()} (available: {', '.join(mi.variants())})")
    typer.echo(f"LLVM {'.'.join(map(str, llvm)) if llvm[0] >= 0 else 'not loaded'} from {tm.LLVM_PATH}")
    for name, (kind, mod) in sorted(tm.plugin_names().items()):
        typer.echo(f"plugin {kind:10s} {name:16s} {mod}")
    from transient_mi.scenes import SCENES_DIR

    # what `transient-mi render NAME` takes by name
    typer.echo(f"scenes {', '.join(sorted(p.stem for p in SCENES_DIR.glob('*.xml')))} (in {SCENES_DIR})")


def register(app: typer.Typer) -> None:
    app.command("info")(info)
