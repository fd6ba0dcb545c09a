"""How the grid programs are compiled: ``grid_jit``, a ``jax.jit`` that picks XLA's CPU code
generator by grid size.

XLA's CPU backend has two fusion code generators. On the paper's grids (up to 65^2) the older one
runs our programs as fast as the newer one and compiles them sooner and with far less memory; above
65^2 the newer one runs the build faster (``SMALL_GRID_CELLS``). Both give the same fabrics
(``tests/core/test_compilation.py`` holds them equal on the built-in scene).
Other backends get plain ``jax.jit``.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import math
import os
import warnings

import jax

SMALL_GRID_CELLS = 65 * 65
"""Grids of at most this many cells (the paper's grids) compile with the older emitters: at 65^2 they
run the full build as fast as the newer ones, on larger grids slower."""

_SMALL_GRID_OPTIONS = {"xla_cpu_use_fusion_emitters": False}


def traced(*trees) -> bool:
    """Whether any leaf of ``trees`` is a tracer (called under a caller's ``jit``, ``vmap``, ``grad``)."""
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(trees))


def _grid_cells(leaves) -> int:
    """The largest trailing 2-D size among arrays ``leaves`` (the grid's cells), 0 when none has one."""
    cells = 0
    for leaf in leaves:
        shape = getattr(leaf, "shape", ())
        if len(shape) >= 2:
            cells = max(cells, math.prod(shape[-2:]))
    return cells


@functools.cache
def _on_cpu() -> bool:
    """Whether JAX's default backend is the CPU (fixed once the backends have started, which this
    call does; cached, as each grid program's call asks)."""
    return jax.default_backend() == "cpu"


class _GridJit:
    """Two ``jax.jit`` of one function, one per code generator; the call goes to the one for its
    grid size (to the default one under a caller's trace, where it is inlined anyway)."""

    def __init__(self, fn, jit_kwargs, cells_of=None):
        self._default = jax.jit(fn, **jit_kwargs)
        self._small = jax.jit(fn, compiler_options=_SMALL_GRID_OPTIONS, **jit_kwargs)
        self._cells_of = cells_of
        functools.update_wrapper(self, fn)

    def _pick(self, args, kwargs):
        leaves = jax.tree_util.tree_leaves((args, kwargs))
        # under a caller's jit, vmap or grad the call is inlined, where compile options are refused
        if not _on_cpu() or traced(leaves):
            return self._default
        cells = _grid_cells(leaves) if self._cells_of is None else self._cells_of(*args, **kwargs)
        return self._small if cells <= SMALL_GRID_CELLS else self._default

    def __call__(self, *args, **kwargs):
        return self._pick(args, kwargs)(*args, **kwargs)

    def _cache_size(self) -> int:
        return self._default._cache_size() + self._small._cache_size()


def grid_jit(fn=None, *, cells_of=None, **jit_kwargs):
    """``jax.jit(fn, **jit_kwargs)`` compiled with the code generator that suits the grid's size
    (module docstring). Usable as ``grid_jit(fn, static_argnums=...)`` or as a decorator.
    cells_of: ``(*args, **kwargs) -> int``, the grid's cells, where no array argument has the
    grid's shape (default: the largest trailing 2-D size among the array arguments)."""
    if fn is None:
        return functools.partial(grid_jit, cells_of=cells_of, **jit_kwargs)
    return _GridJit(fn, jit_kwargs, cells_of)


def single_cpu() -> int:
    """Run JAX's CPU programs on one core; returns the core. Call it before the first JAX computation.

    XLA sizes its CPU thread pool once, from the process's CPU affinity, when the backend starts. On
    the paper's grids the programs are hundreds of tiny operations, and handing them between two
    threads costs about what it gains, while large grids run faster on all cores, and XLA then
    compiles on one core too (``experiments/bench_fabric.py`` with and without ``--single-cpu``
    compares them on any machine). So pin for long re-planning runs on
    small grids, not for large grids or one-off calls. Also ``jaxplan --single-cpu COMMAND`` or
    ``taskset -c 0 python ...``.
    """
    if not hasattr(os, "sched_setaffinity"):
        raise RuntimeError("single_cpu needs os.sched_setaffinity (Linux); use the OS's own pinning "
                           "(e.g. 'taskset -c 0') instead.")
    if _backend_started():
        warnings.warn("single_cpu was called after JAX ran a computation: XLA's thread pool is already "
                      "sized, so this pins only the calling thread. Call it first thing in the process.",
                      RuntimeWarning, stacklevel=2)
    core = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    return core


def limit_malloc_arenas(arenas: int = 1) -> bool:
    """Cap glibc's malloc arenas (``M_ARENA_MAX``) at ``arenas``; returns whether the allocator took it.
    Call it before the first JAX computation (``import jaxplan`` first is fine).

    XLA compiles on several threads, and glibc gives each thread an arena of its own; the memory a
    compilation frees stays in its thread's arena, so every compiled program leaves some behind.
    With one arena it is reused instead, which lowers the peak (``experiments/table2.py``'s memory
    probe measures it; docs/benchmarks.md). The cost is some lock contention between threads that
    allocate at once, which planning hardly does. Threads that have allocated already keep their
    arena, hence "call it first". Same
    as ``MALLOC_ARENA_MAX=1`` in the environment; also ``jaxplan --low-memory COMMAND``. No effect
    (returns False) on other C libraries.
    """
    if int(arenas) < 1:
        raise ValueError(f"limit_malloc_arenas: arenas must be >= 1, got {arenas}.")
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    if _backend_started():
        warnings.warn("limit_malloc_arenas was called after JAX ran a computation: the threads that "
                      "allocated already keep their arenas. Call it first thing in the process.",
                      RuntimeWarning, stacklevel=2)
    return mallopt(_M_ARENA_MAX, int(arenas)) == 1


_M_ARENA_MAX = -8   # glibc's malloc.h


def _backend_started() -> bool:
    """Whether JAX has created its backends (and so XLA's CPU thread pool) in this process."""
    try:
        from jax._src import xla_bridge
    except ImportError:   # pragma: no cover - a JAX without that module: assume not
        return False
    return bool(getattr(xla_bridge, "_backends", None))
