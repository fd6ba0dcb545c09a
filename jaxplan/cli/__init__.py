"""The ``jaxplan`` command line (``jaxplan --help``)."""
from jaxplan.cli.main import main

__all__ = ["main"]
