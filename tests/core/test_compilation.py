"""grid_jit: the code generator is picked by grid size, and both give the same fabric; single_cpu."""
from __future__ import annotations

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan import FabricParams, build_fabric
from jaxplan.core import compilation as _compile
from jaxplan.transport import fabric
from jaxplan.transport.generators import builtin_scene


def _doubler():
    """A fresh function each time: jax keys its compile cache by the function."""
    return lambda a: 2.0 * a


def test_small_grids_take_the_older_emitters_and_large_the_default():
    jitted = _compile.grid_jit(_doubler())
    side = int(np.sqrt(_compile.SMALL_GRID_CELLS))
    small, large = jnp.ones((side, side)), jnp.ones((side + 1, side + 1))
    np.testing.assert_array_equal(np.asarray(jitted(small)), 2.0 * np.ones((side, side)))
    assert (jitted._small._cache_size(), jitted._default._cache_size()) == (1, 0)
    np.testing.assert_array_equal(np.asarray(jitted(large)), 2.0 * np.ones((side + 1, side + 1)))
    assert (jitted._small._cache_size(), jitted._default._cache_size()) == (1, 1)
    assert jitted._cache_size() == 2


def test_grid_size_is_the_largest_trailing_plane_of_any_argument():
    args = ({"a": jnp.zeros((3, 40, 50)), "b": jnp.zeros(7)}, np.zeros((6, 6)))
    assert _compile._grid_cells(jax.tree.leaves(args)) == 2000
    assert _compile._grid_cells(jax.tree.leaves((jnp.zeros(9), 3.0, {"k": 2}))) == 0


def test_cells_of_sizes_the_grid_when_no_argument_has_its_shape():
    # the scene geometry takes the grid's shape as a static tuple, its arrays are boundary segments
    jitted = _compile.grid_jit(lambda a, shape: jnp.zeros(shape) + a[0, 0, 0], static_argnums=1,
                               cells_of=lambda a, shape: shape[0] * shape[1])
    side = int(np.sqrt(_compile.SMALL_GRID_CELLS))
    segments = jnp.ones((3, 2, 2))
    assert jitted._pick((segments, (side, side)), {}) is jitted._small
    assert jitted._pick((segments, (side + 1, side)), {}) is jitted._default
    np.testing.assert_array_equal(np.asarray(jitted(segments, (side + 1, side))), np.ones((side + 1, side)))


def test_inside_a_caller_trace_the_call_inlines():
    jitted = _compile.grid_jit(_doubler())
    outer = jax.jit(lambda a: jitted(a) + 1.0)
    np.testing.assert_array_equal(np.asarray(outer(jnp.ones((4, 4)))), 3.0 * np.ones((4, 4)))
    grads = jax.grad(lambda a: jnp.sum(jitted(a)))(jnp.ones((4, 4)))
    np.testing.assert_array_equal(np.asarray(grads), 2.0 * np.ones((4, 4)))
    assert jitted._small._cache_size() == 0


def test_both_code_generators_build_the_same_fabric():
    scene = builtin_scene()
    params = FabricParams(theta_tol_deg=60.0)
    newer = jax.jit(fabric.fabric_of, compiler_options={"xla_cpu_use_fusion_emitters": True})
    older = build_fabric(scene, params)
    for a, b in zip(jax.tree.leaves(older), jax.tree.leaves(newer(scene, params))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


_PIN_CHECK = """
import os, warnings
import jaxplan
core = jaxplan.single_cpu()
assert os.sched_getaffinity(0) == {core}, os.sched_getaffinity(0)
fabric = jaxplan.build_fabric(jaxplan.builtin_scene("default"))
assert float(fabric.value.max()) > 0
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    jaxplan.single_cpu()          # too late now: XLA's thread pool exists
assert any("thread pool is already" in str(w.message) for w in caught), caught
print("ok")
"""


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs os.sched_setaffinity (Linux)")
def test_single_cpu_pins_a_fresh_process_and_warns_when_called_late():
    # a fresh process: pinning this test worker would slow the rest of the suite
    done = subprocess.run([sys.executable, "-c", _PIN_CHECK], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().endswith("ok")


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs os.sched_setaffinity (Linux)")
def test_cli_single_cpu_flag_runs_a_command_pinned():
    code = ("import os, sys; from jaxplan.cli import main; rc = main(['--single-cpu', 'scenes']); "
            "print('cores', len(os.sched_getaffinity(0))); sys.exit(rc)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "cores 1" in done.stdout


_ARENA_CHECK = """
import warnings
import jaxplan
took = jaxplan.limit_malloc_arenas()
fabric = jaxplan.build_fabric(jaxplan.builtin_scene("default"))
assert float(fabric.value.max()) > 0
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    jaxplan.limit_malloc_arenas()     # too late now: JAX's threads have allocated
assert any("keep their arenas" in str(w.message) for w in caught), caught
print("took", took)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_limit_malloc_arenas_in_a_fresh_process_and_warns_when_called_late():
    # a fresh process: the setting is process-wide
    done = subprocess.run([sys.executable, "-c", _ARENA_CHECK], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().endswith("took True")


def test_limit_malloc_arenas_refuses_fewer_than_one():
    with pytest.raises(ValueError, match="arenas must be >= 1"):
        _compile.limit_malloc_arenas(0)


def test_cli_low_memory_flag_runs_a_command():
    code = "import sys; from jaxplan.cli import main; sys.exit(main(['--low-memory', 'scenes']))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "default" in done.stdout
