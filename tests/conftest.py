"""Test-session set-up: one JAX compilation cache shared by every process of a test run.

Most of the suite's time is XLA compiling the same programs (the fabric for the shapes of
``tests/_scenes.SHAPES``, the episode loop, the physics step) in each pytest-xdist worker and in the
notebook and CLI subprocesses. The controller points JAX's persistent compilation cache at a folder
under the virtual environment (``<venv>/jax-test-cache``, at most ``_CACHE_MAX_BYTES``) before the
workers start; they, and every subprocess they spawn, inherit it through the environment, so a
program compiled in one process, or in an earlier run, is loaded by the others. A fresh clone (as on
CI) starts cold; ``make clean`` empties it with the environment. Outside a virtual environment the
folder is temporary and removed when the run ends. A cache directory set by the user is left alone.

The same hook asks XLA for cheap code generation (``_FAST_COMPILE_FLAGS``, before any ``XLA_FLAGS``
of the user's, which win): the tests' grids are tiny, so compiling dominates their time, and these
flags cut a fabric compile about 4x for code that runs a few times slower. The values agree with
the default build up to float rounding (on a 30 x 30 fabric: integer fields identical, floats
within 1e-5, from operations contracted or ordered differently). Benchmarks and users get XLA's
defaults; ``JAXPLAN_TEST_XLA_DEFAULTS=1`` runs the suite with them too.

A worker that dies mid-test (a crash in native code) is replaced, the test it died in is run once
more there, and the run ends either way (``tests/xdist_crashes.py``).

Property tests draw the same examples on every run (hypothesis profile "suite", derandomized), so a
red suite means a change broke something, not that the search got lucky; ``HYPOTHESIS_PROFILE=explore``
draws fresh examples each run to look for new counterexamples.
"""
from __future__ import annotations

import os
import shutil
import sys
import tempfile

from hypothesis import settings

settings.register_profile("suite", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "suite"))

_CACHE_ENV = "JAX_COMPILATION_CACHE_DIR"
_MIN_COMPILE_SECS = "0.3"   # smaller programs compile faster than they load
_CACHE_MAX_BYTES = str(2 << 30)   # JAX evicts the least recently used entries beyond this
_FAST_COMPILE_FLAGS = "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false"


def pytest_configure(config):
    if hasattr(config, "workerinput"):
        return   # an xdist worker: it inherited the controller's environment
    if config.pluginmanager.hasplugin("xdist") and config.getoption("dist", "no") == "loadscope":
        from tests.xdist_crashes import CrashPlugin

        config.pluginmanager.register(CrashPlugin(), "jaxplan-xdist-crashes")
    if not os.environ.get("JAXPLAN_TEST_XLA_DEFAULTS"):
        os.environ["XLA_FLAGS"] = f"{_FAST_COMPILE_FLAGS} {os.environ.get('XLA_FLAGS', '')}".strip()
    if os.environ.get(_CACHE_ENV):
        return   # the user's own cache
    if sys.prefix != sys.base_prefix:   # a virtual environment: the cache lives (and dies) with it
        path = os.path.join(sys.prefix, "jax-test-cache")
        os.makedirs(path, exist_ok=True)
    else:
        path = tempfile.mkdtemp(prefix="jaxplan-test-jax-cache-")
        config._jaxplan_jax_cache = path
    os.environ[_CACHE_ENV] = path
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", _MIN_COMPILE_SECS)
    os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", _CACHE_MAX_BYTES)
    if "jax" in sys.modules:   # imported before this hook ran (a plugin): its flags are already read
        import jax

        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", float(_MIN_COMPILE_SECS))
        jax.config.update("jax_compilation_cache_max_size", int(_CACHE_MAX_BYTES))


def pytest_unconfigure(config):
    path = getattr(config, "_jaxplan_jax_cache", None)
    if path:
        shutil.rmtree(path, ignore_errors=True)
