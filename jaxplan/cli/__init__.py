"""The ``jaxplan`` command line (``jaxplan --help``). ``main(argv)`` runs it and raises ``SystemExit``
for bad input and interrupts (usable in-process); ``entry()`` runs it as the whole process and ends
it (``python -m jaxplan.cli``)."""
from jaxplan.cli.main import entry, main

__all__ = ["entry", "main"]
