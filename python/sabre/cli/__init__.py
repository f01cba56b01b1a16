"""The command line of ``python -m sabre``: one module per group of subcommands, :func:`main` dispatches."""

from .main import main

__all__ = ["main"]
