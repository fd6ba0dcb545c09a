"""The ``jaxplan`` command line (``jaxplan --help``). ``main(argv)`` runs it and raises ``SystemExit``
for bad input and interrupts (usable in-process); ``entry()`` runs it as the whole process and ends
it (the ``jaxplan`` command, ``python -m jaxplan.cli``).

This module imports only the standard library: ``entry`` makes Ctrl-C, SIGTERM and SIGHUP end the
process with ``128 + signal`` before it imports JAX, so a signal during the seconds of start-up ends
it cleanly too (no traceback, no signal lost in a callback). The commands live in ``app``.
"""
from __future__ import annotations

import os
import signal
import sys

__all__ = ["entry", "main"]

_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


def main(argv=None) -> int:
    """Run the command line with ``argv`` (``jaxplan.cli.app.main``): returns 0, or raises
    ``SystemExit`` (2 for bad input, 128 + signal when interrupted)."""
    from jaxplan.cli import app

    return app.main(argv)


def entry(argv=None):
    """The command line as a whole process (``jaxplan.cli.app.entry``), signals handled from the start."""
    for s in _SIGNALS:
        signal.signal(s, _leave_while_starting)
    from jaxplan.cli import app

    app.entry(argv)


def _leave_while_starting(signum, frame):
    """Before the command runs nothing has been written: end the process at once, as a signal would,
    with 128 + signal (``os._exit``: tearing down half-imported XLA can crash)."""
    try:
        print("interrupted", file=sys.stderr, flush=True)
    finally:
        os._exit(128 + signum)
