"""Interrupts of real ``python -m jaxplan.cli`` processes (issue 47): a few fixed trials of
``experiments.interrupts``, whose full run sends SIGINT and SIGTERM at random moments. Each trial's
process exits with 128 + the signal (or 0 when it finished first), with no traceback, an
``interrupted:`` last line, a run.json that does not say ``running``, and nothing outside its folder.

The delays hit the compile of each command and stay past Python's start-up: a signal that arrives
while Python still imports jaxplan and JAX, before the CLI runs, gets Python's default handling
(the experiment counts those apart, as ``startup``)."""
from __future__ import annotations

import pytest

from experiments.interrupts import run_trial

TRIALS = [   # (command, signal, seconds after the start): each one lands in the command's compile
    ("fleet", "SIGINT", 12.0),     # the report: SIGINT during the fleet's compile segfaulted at exit
    ("demo", "SIGTERM", 8.0),
    ("sweep", "SIGINT", 6.0),
    ("pusharound", "SIGTERM", 6.0),
]


@pytest.mark.parametrize(("command", "signame", "delay"), TRIALS, ids=[f"{c}-{s}" for c, s, _ in TRIALS])
def test_an_interrupt_mid_compile_exits_cleanly(command, signame, delay):
    t = run_trial(command, signame, delay)
    assert t["ok"], f"{t['failures']}\n{t['stderr_tail']}"
    assert t["outcome"] in ("interrupted", "finished"), t
    assert t["manifest_status"] != "running" and not t["files_outside"]
    if t["outcome"] == "interrupted":
        assert t["last_line"].startswith("interrupted")
