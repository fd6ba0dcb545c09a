"""Interrupts that are never lost: Ctrl-C (SIGINT), SIGTERM (``timeout``, systemd, Slurm, docker) and
SIGHUP (a closed terminal) stop a command and leave its output folder as an interrupted run.

Within :func:`stop_signals_interrupt`, each of these signals raises an interrupt in the main thread:
``KeyboardInterrupt`` for Ctrl-C, :class:`StopSignal` (a ``KeyboardInterrupt`` that remembers the
signal) for the others. Python runs a signal handler between any two bytecodes, also inside a callback
that C code calls and whose exceptions it only prints (JAX's garbage-collection callback is one), so
an interrupt raised there is lost. The handler therefore also records the signal, and the host
drivers' loops call :func:`check_interrupt` once per step, which raises it again if it was lost.
:func:`signal_number` says which signal an interrupt came from, so that a command exits with
``128 + signal``, as shells report it.
"""
from __future__ import annotations

import contextlib
import signal
import threading

__all__ = ["INTERRUPT_SIGNALS", "StopSignal", "check_interrupt", "signal_name", "signal_number",
           "stop_signals_interrupt"]

INTERRUPT_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))

_pending: list[int] = []   # signals received and not yet raised where they could not be swallowed


class StopSignal(KeyboardInterrupt):
    """The process received ``signum`` (SIGTERM or SIGHUP), handled like Ctrl-C."""

    def __init__(self, signum: int, *args):
        super().__init__(*args)
        self.signum = int(signum)


def signal_number(exc: BaseException) -> int:
    """The signal an interrupt came from: its ``signum`` if it carries one, else SIGINT (Ctrl-C)."""
    return int(getattr(exc, "signum", signal.SIGINT))


def signal_name(signum: int) -> str:
    """``"SIGTERM"`` for 15, and so on."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def _interrupt(signum: int) -> KeyboardInterrupt:
    return KeyboardInterrupt() if signum == signal.SIGINT else StopSignal(signum)


def _handle(signum, frame):
    _pending.append(int(signum))
    raise _interrupt(signum)


def check_interrupt() -> None:
    """Raise the interrupt of a signal received under :func:`stop_signals_interrupt` that has not
    stopped the program yet (its first raise was swallowed); otherwise do nothing. Cheap: call it
    once per step of a long loop."""
    if _pending:
        signum = _pending[-1]
        _pending.clear()
        raise _interrupt(signum)


@contextlib.contextmanager
def stop_signals_interrupt():
    """Within the block, SIGINT, SIGTERM and SIGHUP raise an interrupt in the main thread and are
    recorded for :func:`check_interrupt`; the previous handlers come back afterwards. Outside the
    main thread (where Python cannot install handlers) the block runs unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _pending.clear()
    previous = {s: signal.signal(s, _handle) for s in INTERRUPT_SIGNALS}
    try:
        yield
        check_interrupt()   # one that arrived at the very end, inside a callback
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        _pending.clear()
