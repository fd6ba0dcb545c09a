"""The suite's xdist plugin (``tests/xdist_crashes.py``): a worker killed mid-test is replaced, the
run ends, a crash that does not recur is re-run and reported, one that recurs fails the test."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("xdist")

REPO = Path(__file__).resolve().parents[2]

# Two modules of three tests (loadscope: one module per worker at first). test_b_dies kills its
# worker with SIGSEGV the first time it runs (a marker file remembers it) or every time.
MODULE_A = """
def test_a1(): pass
def test_a2(): pass
def test_a3(): pass
"""
MODULE_B = """
import os, signal, pathlib
MARK = pathlib.Path(__file__).with_name("died-once")
def test_b1(): pass
def test_b_dies():
    if {always} or not MARK.exists():
        MARK.touch()
        os.kill(os.getpid(), signal.SIGSEGV)
def test_b3(): pass
"""
CONFTEST = """
def pytest_configure(config):
    if config.pluginmanager.hasplugin("xdist") and not hasattr(config, "workerinput"):
        from tests.xdist_crashes import CrashPlugin
        config.pluginmanager.register(CrashPlugin(), "jaxplan-xdist-crashes")
"""


def _run(tmp_path, always: bool):
    (tmp_path / "conftest.py").write_text(CONFTEST)
    (tmp_path / "test_a.py").write_text(MODULE_A)
    (tmp_path / "test_b.py").write_text(textwrap.dedent(MODULE_B.format(always=always)))
    cmd = [sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadscope", "-q", "-p", "no:cacheprovider",
           str(tmp_path)]
    # the hang this plugin prevents would run into the timeout (an error here, not a stuck suite)
    return subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(REPO)})


def test_a_crash_that_does_not_recur_is_rerun_and_reported(tmp_path):
    out = _run(tmp_path, always=False)
    text = out.stdout + out.stderr
    assert out.returncode == 0, text
    assert "6 passed, 1 rerun" in text
    assert "a worker died while running test_b.py::test_b_dies" in text


def test_a_crash_that_recurs_fails_the_test_and_the_run_ends(tmp_path):
    out = _run(tmp_path, always=True)
    text = out.stdout + out.stderr
    assert out.returncode == 1, text
    assert "1 failed" in text and "1 rerun" in text
    assert "crashed while running 'test_b.py::test_b_dies'" in text
    assert "5 passed" in text   # every other test ran, test_b3 included
