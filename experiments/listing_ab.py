"""How the selective rebuild lists its dirty cells: whole-grid dilation against the breadth-first queue.

The measurement behind ``rebuild.DENSE_LISTING_CELLS``. For each grid side, Table 2's random scenes
(``bench_fabric.make_scene``, density 0.4, ``--seeds`` seeds) get ``--ticks`` pushes of their best
route. After each push both listings run on the same grid in one process, alternating, ``--repeats``
calls each (median), and must give the same dirty set. Writes
``experiments/results/listing_ab.{json,md}``.

    python -m experiments.listing_ab                       # 45, 65, 128, 256
    python -m experiments.listing_ab --sizes 65 --ticks 2  # quick
"""
from __future__ import annotations

import argparse
import datetime as _dt
import statistics
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):   # run as a script: make ``experiments`` importable
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from experiments._results import write_results  # noqa: E402
from experiments.bench_fabric import RESULTS_DIR, environment, make_scene  # noqa: E402


def _pushes(n: int, seed: int, ticks: int, params, spill):
    """``(scene after the push, fabric before it, changed)`` for each of ``ticks`` pushes."""
    import jax

    from experiments.table2 import _best_route
    from jaxplan import build_fabric, execute, rebuild

    best_route = jax.jit(_best_route, static_argnums=2)
    scene = make_scene(n, 0.4, seed)
    scene = scene.with_obj(execute.quantize(scene.obj))
    fabric = build_fabric(scene, params)
    for _ in range(ticks):
        route, any_left = best_route(scene, fabric, 8 * n)
        if not bool(any_left):
            return
        new_obj, push = execute.execute_jit(scene, route, spill)
        scene = scene.with_obj(new_obj)
        yield scene, fabric, push.changed
        fabric, _ = rebuild.selective_rebuild(scene, params, fabric, push.changed)


def measure(n: int, args, params, spill) -> dict:
    import jax

    from jaxplan import rebuild

    capacity = rebuild.default_capacity((n, n))
    times = {True: [], False: []}
    for seed in range(args.seeds):
        for scene, fabric, changed in _pushes(n, seed, args.ticks, params, spill):
            run = {dense: (lambda dense=dense: rebuild._listing_jit(scene, params, fabric, changed, capacity, dense))
                   for dense in (True, False)}
            outs = {dense: jax.block_until_ready(fn()) for dense, fn in run.items()}
            if not np.array_equal(np.asarray(outs[True][2]), np.asarray(outs[False][2])):
                raise AssertionError(f"{n}x{n} seed {seed}: the two listings disagree")
            tick = {True: [], False: []}
            for _ in range(args.repeats):
                for dense, fn in run.items():
                    start = time.perf_counter()
                    jax.block_until_ready(fn())
                    tick[dense].append((time.perf_counter() - start) * 1e3)
            for dense in times:
                times[dense].append(statistics.median(tick[dense]))
    dense, queue = statistics.median(times[True]), statistics.median(times[False])
    return {"n": n, "pushes": len(times[True]), "dilation_ms": dense, "queue_ms": queue, "ratio": dense / queue,
            "default_dense": rebuild.dense_listing_default((n, n))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[45, 65, 128, 256])
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--ticks", type=int, default=6, help="pushes per seed")
    p.add_argument("--repeats", type=int, default=30, help="calls of each listing per push")
    p.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = p.parse_args(argv)
    from jaxplan import FabricParams, SpillParams

    params, spill = FabricParams(theta_tol_deg=60.0), SpillParams(lam=0.05)
    rows = [measure(n, args, params, spill) for n in args.sizes]
    result = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "environment": environment(False),
              "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}, "rows": rows}
    lines = ["# Listing the dirty cells: whole-grid dilation vs breadth-first queue", "",
             f"{result['date']}, {result['environment']['cpus_available']} cores. Density 0.4, {args.seeds} seeds x "
             f"{args.ticks} pushes; per push the median of {args.repeats} alternating calls of each listing "
             "program (dispatch and block included); medians over pushes. Same dirty sets in every push.", "",
             "| grid | pushes | dilation ms | queue ms | dilation / queue | default |", "|---|---:|---:|---:|---:|---|"]
    lines += [f"| {r['n']}x{r['n']} | {r['pushes']} | {r['dilation_ms']:.3f} | {r['queue_ms']:.3f} | {r['ratio']:.2f} | "
              f"{'dilation' if r['default_dense'] else 'queue'} |" for r in rows]
    write_results(args.results_dir, "listing_ab", result, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
