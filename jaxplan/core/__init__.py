"""Parts every system shares: the grid lattice and its stencils, compilation settings, timing.

- ``lattice``: the 8-connected grid (directions, shifts, neighbours, cell centres, index helpers).
- ``compilation``: ``grid_jit`` (jit with grid-size-aware XLA options), ``single_cpu``,
  ``limit_malloc_arenas``.
- ``timing``: wall-clock timing of JAX calls.
- ``outputs``: files written atomically and output folders with a ``run.json`` manifest (``RunFolder``).
- ``memory``: ``available_memory_bytes``, the room a cost estimate is checked against.
- ``signals``: Ctrl-C, SIGTERM and SIGHUP as interrupts that are never lost (``stop_signals_interrupt``,
  ``check_interrupt``).
"""
from jaxplan.core import lattice
from jaxplan.core.animation import save_animation
from jaxplan.core.compilation import SMALL_GRID_CELLS, grid_jit, limit_malloc_arenas, single_cpu, traced
from jaxplan.core.files import path_kind, read_text, shown_path
from jaxplan.core.memory import available_memory_bytes
from jaxplan.core.outputs import RunFolder, RunInterrupted, atomic_write, read_manifest
from jaxplan.core.signals import (
           INTERRUPT_SIGNALS,
           StopSignal,
           check_interrupt,
           signal_name,
           signal_number,
           stop_signals_interrupt,
)
from jaxplan.core.timing import timed

__all__ = ["INTERRUPT_SIGNALS", "RunFolder", "RunInterrupted", "SMALL_GRID_CELLS", "StopSignal", "atomic_write",
           "available_memory_bytes", "check_interrupt", "grid_jit", "lattice", "limit_malloc_arenas", "path_kind",
           "read_manifest", "read_text", "save_animation", "shown_path", "signal_name", "signal_number",
           "single_cpu", "stop_signals_interrupt", "timed", "traced"]
