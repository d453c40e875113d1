"""The ``drrl`` command: ``commands`` (train, eval, render), ``compare`` (drrl compare), ``settings`` (drrl train's
settings options, drawn from the schema) and ``params`` (parameter types)."""

from drrl.cli.commands import main

__all__ = ["main"]
