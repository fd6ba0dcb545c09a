"""Parameter sweeps: the cartesian product of a spec, evaluated in ``vmap``ped chunks, one CSV row per
setting (docs/sweeps.md).

``spec`` validates a spec into its settings, ``chunks`` evaluates a chunk of settings in one jitted
kernel, ``run`` drives a sweep into a resumable CSV, locally or on Ray (``ray``).
"""
from jaxplan.sweep.chunks import Chunk, bytes_per_table, chunk_size_for, evaluate_chunk, metrics_of, with_highways
from jaxplan.sweep.run import MAX_BUDGET_MB, plan_chunks, run_sweep
from jaxplan.sweep.spec import MAX_SETTINGS, METRICS, Settings, SweepSpec, columns_of, load_spec, settings_of, tables_of

__all__ = ["Chunk", "MAX_BUDGET_MB", "MAX_SETTINGS", "METRICS", "Settings", "SweepSpec", "bytes_per_table",
           "chunk_size_for", "columns_of", "evaluate_chunk", "load_spec", "metrics_of", "plan_chunks", "run_sweep",
           "settings_of", "tables_of", "with_highways"]
