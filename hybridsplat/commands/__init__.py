"""CLI commands, one module per command group.

Each module defines ``register(app: typer.Typer) -> None``; :mod:`hybridsplat.cli` discovers and calls
them, so adding a command means adding a module here and nothing else.
"""
