"""The fleet's fabric refresh, selective against full, in the fleet's one compiled step.

A coordinated fleet runs ``--steps`` steps on the site, once per rebuild ("full", "selective"); for
each: the first call of the jitted step (compile and one step) and the median wall time of the
steps that applied a push and assigned none (the refresh, with motion), and whether both runs gave
the same rover cells and counts at every step. Results: ``experiments/results/fleet_rebuild.{json,md}``.

    python -m experiments.fleet_rebuild                  # site128, 4 rovers, 400 steps
    python -m experiments.fleet_rebuild --site site256 --rovers 8
"""
from __future__ import annotations

import argparse
import datetime as _dt
import platform
import statistics
import time
from pathlib import Path

import jax
import numpy as np

from experiments.results_io import write_results
from jaxplan import FabricParams
from jaxplan.fleet import FleetConfig, reset, site, step
from jaxplan.transport import EpisodeParams
from jaxplan.transport.spillage import SpillParams

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def _run(scene, n: int, steps: int, rebuild: str) -> dict:
    params, spill, ep = FabricParams(), SpillParams(), EpisodeParams(max_pushes=0, rebuild=rebuild)
    config = FleetConfig(n, "coordinated")
    state = jax.jit(reset, static_argnames="config")(scene, params, spill, ep, config, max_pushes=1_000_000)
    jitted = jax.jit(step, static_argnames=("config", "evaluator"))
    start = time.perf_counter()
    state, _ = jax.block_until_ready(jitted(state, params, spill, ep, config))
    first_s = time.perf_counter() - start
    refresh_ms, cells, counts = [], [], []
    for _ in range(steps):
        start = time.perf_counter()
        state, rec = jitted(state, params, spill, ep, config)
        rec = jax.device_get(rec)
        ms = 1e3 * (time.perf_counter() - start)
        if rec.ended.any() and not rec.assigned.any():
            refresh_ms.append(ms)
        cells.append(np.asarray(rec.pos))
        counts.append(np.asarray(state.scene.obj))
    return {"rebuild": rebuild, "first_call_s": round(first_s, 1), "refresh_steps": len(refresh_ms),
            "refresh_step_ms": statistics.median(refresh_ms) if refresh_ms else None,
            "cells": np.stack(cells), "counts": np.stack(counts)}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.fleet_rebuild", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="example:\n  python -m experiments.fleet_rebuild --rovers 4")
    parser.add_argument("--site", default="site128", help="built-in fleet site; default site128")
    parser.add_argument("--rovers", type=int, default=4, help="fleet size; default 4")
    parser.add_argument("--steps", type=int, default=400, help="steps per run; default 400")
    args = parser.parse_args(argv)
    scene = site(args.site)
    runs = [_run(scene, args.rovers, args.steps, mode) for mode in ("full", "selective")]
    same = bool(np.array_equal(runs[0]["cells"], runs[1]["cells"]) and
                np.array_equal(runs[0]["counts"], runs[1]["counts"]))
    rows = [{k: v for k, v in r.items() if k not in ("cells", "counts")} for r in runs]
    meta = (f"{_dt.datetime.now(_dt.UTC).isoformat(timespec='seconds')}, {platform.platform()}, jax "
            f"{jax.__version__}; {args.site}, coordinated, {args.rovers} rovers, {args.steps} steps.")
    lines = [f"# The fleet's fabric refresh: selective against full\n\n{meta}\n",
             "| rebuild | first call (compile + 1 step), s | steps that refreshed | refresh step, ms (median) |",
             "|---|---:|---:|---:|"]
    lines += [f"| {r['rebuild']} | {r['first_call_s']} | {r['refresh_steps']} | "
              f"{r['refresh_step_ms']:.1f} |" for r in rows]
    lines.append(f"\nSame rover cells and counts at every step: {same}.")
    write_results(RESULTS_DIR, "fleet_rebuild", {"meta": meta, "rows": rows, "same": same}, "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
