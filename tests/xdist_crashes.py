"""A pytest-xdist plugin: a worker that dies mid-test neither hangs the run nor goes unreported.

The suite runs with ``--dist loadscope`` (a module's compiled fixtures are built once per worker).
When a worker process dies (a segmentation fault in native code, say), pytest-xdist 3.8's
``LoadScopeScheduling.remove_node`` puts every module the dead worker ever ran back on the queue,
finished ones included; a finished module reaches the replacement worker as an empty batch, and a
worker given one last test waits for a second that never comes: the run hangs until it is killed
(pytest-xdist issues 1323, 1327 and 1378). ``CrashTolerantLoadScope`` re-queues only the modules
with tests still to run, and tells a worker that the queue is empty as soon as it is, so the run
always ends.

The test the worker died in is run once more on the replacement worker: a crash that recurs fails
the test as before, one that does not is reported as ``rerun`` (``R``) with a line in the summary
naming the test, so a rare crash in a native library neither fails the run silently nor passes it
unseen. ``RERUNS`` crashes of one test are re-run; the next fails it.
"""
from __future__ import annotations

from collections import Counter

import pytest
from xdist.scheduler import LoadScopeScheduling

RERUNS = 1


class CrashTolerantLoadScope(LoadScopeScheduling):
    """``LoadScopeScheduling`` that re-queues only unfinished work of a dead worker."""

    def __init__(self, config, log=None):
        super().__init__(config, log)
        self.crashes: Counter[str] = Counter()

    def remove_node(self, node):
        workload = self.assigned_work.pop(node)
        unfinished = {scope: unit for scope, unit in workload.items() if not all(unit.values())}
        if not unfinished:
            return None
        # the worker runs its tests in order: the first one not finished is the one it died in
        crashitem = next(nodeid for unit in unfinished.values() for nodeid, done in unit.items() if not done)
        self.crashes[crashitem] += 1
        if self.crashes[crashitem] > RERUNS:
            for unit in unfinished.values():
                unit.pop(crashitem, None)
            unfinished = {scope: unit for scope, unit in unfinished.items() if unit and not all(unit.values())}
        self.workqueue.update(unfinished)
        for other in self.assigned_work:
            self._reschedule(other)
        return crashitem

    def _assign_work_unit(self, node):
        super()._assign_work_unit(node)
        if not self.workqueue:
            node.shutdown()   # a worker starts its last test only once it knows no other will come


class CrashPlugin:
    """Registered by ``tests/conftest.py`` when pytest-xdist runs the suite with ``--dist loadscope``."""

    def __init__(self):
        self.sched: CrashTolerantLoadScope | None = None
        self.reruns: list[str] = []

    @pytest.hookimpl(tryfirst=True)
    def pytest_xdist_make_scheduler(self, config, log):
        self.sched = CrashTolerantLoadScope(config, log)
        return self.sched

    def pytest_handlecrashitem(self, crashitem, report, sched):
        if self.sched is not None and self.sched.crashes[crashitem] <= RERUNS:
            report.outcome = "rerun"
            self.reruns.append(crashitem)

    def pytest_report_teststatus(self, report, config):
        if report.outcome == "rerun":
            return "rerun", "R", ("RERUN", {"yellow": True})
        return None

    def pytest_terminal_summary(self, terminalreporter):
        if self.reruns:
            terminalreporter.write_sep("=", "worker crashes", yellow=True)
            for nodeid in self.reruns:
                terminalreporter.write_line(f"a worker died while running {nodeid}; it was run again on a "
                                            "fresh worker (its own result is reported above)")
