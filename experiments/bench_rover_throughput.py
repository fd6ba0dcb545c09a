"""Throughput of batched route checks against batch size: MJX and the C engine in the same run.

Issue 7, section 4: "throughput of batched route checks (routes x steps per second) for MJX and for
the C engine, on CPU in the same run, and on a GPU when one is lent". ``bench_rover.py`` measures
both engines on a CPU at batch 2; this script sweeps the batch size, which is what decides the
comparison on a GPU (MJX's step is one fused computation over the whole batch, so its cost per step
hardly grows with the batch until the chip is full; the C engine spreads rollouts over CPU threads).

Protocol. The first ``--routes`` routes of the scene (largest J first, ``bridge.plan_routes``) are
tiled to a batch of B rollouts (element i is route i mod routes; ``check_routes`` jitters each
element's particle layout by its index). Each engine rolls the batch out for ``--ticks`` control
ticks (x the world's substeps) once cold (MJX: tracing and XLA compilation, one per batch size;
C: the batched policy's jit) and ``--repeats`` times warm; reported: the median warm wall time of
``Simulator.run`` alone (physics, policy and transfers; route setup and scoring excluded, they are
the same host code for both engines), and of the whole ``check_routes`` call.
Throughput = B x ticks x substeps / warm physics time. The C engine uses every CPU core
(``Simulator(nthread=None)``); batches over ``--c-max-batch`` are skipped for it (time).

``--solver Newton`` builds the world with MuJoCo's Newton solver instead of CG (the A/B behind the
solver choice, docs/physics.md).

Results: ``experiments/results/rover_throughput_<device>[_newton].json`` and ``.md`` (device ``gpu``
when JAX sees one, else ``cpu``; ``--results-dir`` to write elsewhere), written after every engine so
that an interrupted run keeps what it measured.

Examples::

    python -m experiments.bench_rover_throughput --batches 2 8 --ticks 40          # CPU smoke run
    python -m experiments.bench_rover_throughput --batches 16 128 1024 --ticks 400  # on a GPU
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from jaxplan.transport.physics import plan_routes, world_for_routes

RESULTS_DIR = Path(__file__).resolve().parent / "results"


class _TimedSimulator:
    """A ``Simulator`` whose ``run`` records its own wall time (physics only, results on the host)."""

    def __init__(self, sim):
        self.sim = sim
        self.last_s = float("nan")

    @property
    def tick_seconds(self):
        return self.sim.tick_seconds

    def run(self, *args, **kwargs):
        t0 = time.perf_counter()
        out = self.sim.run(*args, **kwargs)   # returns numpy arrays: the device work is finished
        self.last_s = time.perf_counter() - t0
        return out


def tile_routes(routes, batch):
    import jax

    b = int(np.asarray(routes.n_cells).shape[0])
    idx = np.arange(batch) % b
    return jax.tree.map(lambda a: np.asarray(a)[idx], routes)


def measure_engine(scene, routes, world, backend, n_ticks, repeats):
    from jaxplan.physics import Simulator
    from jaxplan.transport.physics import check_routes, pursuit_policy

    sim = _TimedSimulator(Simulator(world.model, pursuit_policy, substeps=world.config.substeps,
                                    bounds=world.bounds, backend=backend))
    t0 = time.perf_counter()
    chk = check_routes(scene, routes, n_ticks=n_ticks, world=world, simulator=sim)
    cold = time.perf_counter() - t0
    cold_physics = sim.last_s
    physics, whole = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        chk = check_routes(scene, routes, n_ticks=n_ticks, world=world, simulator=sim)
        whole.append(time.perf_counter() - t0)
        physics.append(sim.last_s)
    o = chk.outcome
    return {"ticks": chk.n_ticks, "cold_s": cold, "cold_physics_s": cold_physics,
            "warm_physics_s": physics, "warm_check_s": whole, "physics_median_s": float(np.median(physics)),
            "check_median_s": float(np.median(whole)),
            "finite": float(np.mean(o.finite)), "reached": float(np.mean(o.reached)),
            "delivered": np.asarray(o.delivered, float).tolist(),
            "mean_lateral": np.asarray(o.mean_lateral, float).tolist()}


def _agreement(c, m):
    dc, dm = np.asarray(c["delivered"]), np.asarray(m["delivered"])
    lc, lm = np.asarray(c["mean_lateral"]), np.asarray(m["mean_lateral"])
    return {"max_abs_delivered_diff": float(np.max(np.abs(dc - dm))),
            "mean_abs_delivered_diff": float(np.mean(np.abs(dc - dm))),
            "max_abs_lateral_diff_cells": float(np.max(np.abs(lc - lm)))}


def _frac(x):
    return "" if x is None else f"{x:.2f}"


def to_markdown(r):
    L = [f"# Rover throughput against batch size ({r['device']})", "",
         f"{r['date']}, {r['host']['platform']}, {r['host']['cpus']} CPUs, jax {r['host']['jax']}, "
         f"mujoco {r['host']['mujoco']}, devices {r['host']['jax_devices']}.", "",
         f"Scene `{r['scene']}`, its first {r['routes']} routes tiled to the batch, {r['ticks']} control ticks x "
         f"{r['substeps']} substeps, {r['particle_bodies']} particle bodies (nq {r['nq']}), "
         f"{r.get('solver', 'Newton')} solver. Physics = "
         "`Simulator.run` alone (median of warm repeats); check = the whole `check_routes` call (route setup, "
         "physics, scoring); cold = the first call (MJX: compilation for this batch size). The C engine uses "
         f"all {r['host']['cpus']} CPU threads.", "",
         "| batch | ticks | engine | cold (s) | physics warm (s) | check warm (s) | route-steps/s | finite | reached |",
         "|---|---|---|---|---|---|---|---|---|"]
    for row in r["rows"]:
        for be in ("c", "mjx"):
            e = row["engines"].get(be)
            if e is None:
                continue
            L.append(f"| {row['batch']} | {row['ticks']} | {'C engine' if be == 'c' else 'MJX'} | {e['cold_s']:.1f} "
                     f"| {e['physics_median_s']:.2f} | {e['check_median_s']:.2f} "
                     f"| {e['route_steps_per_s']:,.0f} | {_frac(e.get('finite'))} | {_frac(e.get('reached'))} |")
    L.append("")
    for row in r["rows"]:
        if "mjx_over_c" not in row:
            continue
        line = f"- batch {row['batch']}: MJX / C throughput {row['mjx_over_c']:.3g}"
        a = row.get("agreement")
        if a:
            line += (f"; delivered mass differs by at most {a['max_abs_delivered_diff']:.1f} objects (mean "
                     f"{a['mean_abs_delivered_diff']:.2f}), mean lateral error by at most "
                     f"{a['max_abs_lateral_diff_cells']:.4f} cell")
        L.append(line + ".")
    L += ["", f"Total script time {r['total_s']:.0f} s.", ""]
    return "\n".join(L)


def _save(result, stem, t_start, row, n_ticks):
    """Write the results so far (after every engine: a run stopped by a time limit keeps them)."""
    row["ticks"] = n_ticks
    result["total_s"] = time.perf_counter() - t_start
    stem.with_suffix(".json").write_text(json.dumps(result, indent=1))
    stem.with_suffix(".md").write_text(to_markdown(result))


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m experiments.bench_rover_throughput",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="default",
                    help="built-in scene, or 'small' (bench_rover's few piles on a 6 x 12 grid); default: default")
    ap.add_argument("--routes", type=int, default=6, help="distinct routes tiled to each batch (default 6)")
    ap.add_argument("--batches", type=int, nargs="+", default=[2, 8], help="batch sizes (default: 2 8)")
    ap.add_argument("--ticks", type=int, default=40,
                    help="control ticks per rollout (default 40; 0: whole routes, check_routes' own horizon)")
    ap.add_argument("--repeats", type=int, default=2, help="warm repeats per engine and batch (default 2)")
    ap.add_argument("--engines", nargs="+", default=["c", "mjx"], choices=["c", "mjx"])
    ap.add_argument("--c-max-batch", type=int, default=256, help="largest batch run on the C engine (time)")
    ap.add_argument("--solver", default="CG", choices=["CG", "Newton"],
                    help="the rover world's constraint solver (RoverConfig.solver; default CG)")
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = ap.parse_args(argv)
    if args.ticks < 0:
        ap.error("--ticks: must be >= 0")
    for name in ("routes", "repeats"):
        if getattr(args, name) < 1:
            ap.error(f"--{name}: must be >= 1")
    if min(args.batches) < 1:
        ap.error("--batches: every batch size must be >= 1")

    import jax
    import mujoco

    from experiments.bench_rover import small_scene
    from jaxplan import builtin_scene
    from jaxplan.transport.physics import RoverConfig

    t_start = time.perf_counter()
    gpu = any(d.platform == "gpu" for d in jax.devices())
    device = "gpu" if gpu else "cpu"
    scene = small_scene() if args.scene == "small" else builtin_scene(args.scene)
    _, routes, _ = plan_routes(scene, n_routes=args.routes)
    n_distinct = int(np.asarray(routes.n_cells).shape[0])
    world = world_for_routes(scene, routes, RoverConfig(solver=args.solver))
    sub = world.config.substeps
    result = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "device": device,
              "host": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": os.cpu_count(),
                       "jax": jax.__version__, "jax_devices": [str(d) for d in jax.devices()],
                       "mujoco": mujoco.__version__},
              "scene": args.scene, "routes": n_distinct, "ticks": args.ticks or "whole routes", "substeps": sub,
              "particle_bodies": world.n_particles, "nq": int(world.model.nq), "solver": world.config.solver,
              "rows": []}
    args.results_dir.mkdir(parents=True, exist_ok=True)
    stem = args.results_dir / f"rover_throughput_{device}{'' if args.solver == 'CG' else '_' + args.solver.lower()}"
    for batch in args.batches:
        batch_routes = tile_routes(routes, batch)
        n_ticks = args.ticks or None   # None: the first engine's run fixes the whole-route horizon
        row = {"batch": batch, "engines": {}}
        result["rows"].append(row)
        for be in args.engines:
            if be == "c" and batch > args.c_max_batch:
                continue
            e = measure_engine(scene, batch_routes, world, be, n_ticks, args.repeats)
            n_ticks = e["ticks"]
            e["route_steps_per_s"] = batch * n_ticks * sub / e["physics_median_s"]
            row["engines"][be] = e
            print(f"batch {batch:5d} {be:3s}: cold {e['cold_s']:7.1f} s, physics {e['physics_median_s']:7.2f} s, "
                  f"check {e['check_median_s']:7.2f} s, {e['route_steps_per_s']:12,.0f} route-steps/s", flush=True)
            _save(result, stem, t_start, row, n_ticks)
        if {"c", "mjx"} <= set(row["engines"]):
            c, m = row["engines"]["c"], row["engines"]["mjx"]
            row["mjx_over_c"] = m["route_steps_per_s"] / c["route_steps_per_s"]
            row["agreement"] = _agreement(c, m)
        _save(result, stem, t_start, row, n_ticks)
    print(to_markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
