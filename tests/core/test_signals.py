"""Interrupts are never lost: inside ``stop_signals_interrupt`` Ctrl-C, SIGTERM and SIGHUP raise at
once, and an interrupt swallowed where it was raised (a callback whose C caller only prints its
exceptions, as JAX's garbage-collection callback is) is raised again by ``check_interrupt``."""
from __future__ import annotations

import signal

import pytest

from jaxplan.core.signals import StopSignal, check_interrupt, signal_number, stop_signals_interrupt


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_raises_an_interrupt_that_names_it(signum):
    with pytest.raises(KeyboardInterrupt) as info, stop_signals_interrupt():
        signal.raise_signal(signum)
    assert signal_number(info.value) == signum
    assert isinstance(info.value, StopSignal) == (signum != signal.SIGINT)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_swallowed_interrupt_is_raised_again_at_the_next_check(signum):
    with pytest.raises(KeyboardInterrupt) as info, stop_signals_interrupt():
        try:                       # the swallowing caller
            signal.raise_signal(signum)
        except KeyboardInterrupt:
            pass
        check_interrupt()
        pytest.fail("check_interrupt did not raise")
    assert signal_number(info.value) == signum


def test_a_swallowed_interrupt_at_the_very_end_still_stops_the_block():
    with pytest.raises(StopSignal), stop_signals_interrupt():
        try:
            signal.raise_signal(signal.SIGTERM)
        except KeyboardInterrupt:
            pass


def test_handlers_come_back_and_nothing_is_left_pending():
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), stop_signals_interrupt():
        signal.raise_signal(signal.SIGINT)
    assert signal.getsignal(signal.SIGTERM) is before
    check_interrupt()   # nothing pending: no raise


def test_an_interrupt_while_an_animation_is_written_stays_an_interrupt(tmp_path):
    """Found by experiments/interrupts.py: a SIGTERM before the GIF's first frame became matplotlib's
    IndexError (its writer finishes the file in a finally clause), so the run was marked failed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxplan.core import save_animation

    def draw(i):
        raise StopSignal(signal.SIGTERM)

    with pytest.raises(StopSignal):
        save_animation(plt.figure(), draw, 3, tmp_path / "a.gif", fps=2, dpi=40)
