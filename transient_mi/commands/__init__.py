"""Sub-commands of ``transient-mi``.

Each module here defines ``register(app: typer.Typer) -> None`` that adds its
command(s); :mod:`transient_mi.cli` discovers and registers them all.
"""
