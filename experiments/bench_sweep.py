"""Benchmark of sweeps: settings evaluated per second on 65x65, vmapped chunks vs a Python loop of jitted calls.

One run measures, side by side and after compilation (every program is called once before timing):

- **loop**: a Python loop over the settings calling the jitted single-setting program (``build_fabric``
  plus the sweep's metrics, ``jaxplan.sweep.metrics_of``) once per setting; the calls are dispatched
  asynchronously and the loop waits for the last result (JAX's normal pipelining);
- **loop (build_fabric only)**: the same loop over plain ``jaxplan.build_fabric`` (no metrics);
- **vmapped**: ``jaxplan.sweep.evaluate_chunk`` on chunks of ``B`` settings (``jit(vmap(...))``, the
  sweep's kernel), for each ``B`` of ``--chunks``.

Settings: random 65x65 scenes (density 0.4, ``jaxplan.sweep.random_scene``) x theta_tol x tau_h x spill
lambda. Each timing is the median of ``--repeats`` passes over all settings (the methods interleaved
round-robin); the ratio is vmapped settings/s over loop settings/s measured in the same run. The
solver's round counts per setting are
reported too: a vmapped ``while_loop`` runs until its slowest member converges, which is the main cost
of batching settings whose DP needs different numbers of rounds.

Results: a markdown table on stdout, ``experiments/results/sweep.json`` and ``sweep.md``
(``sweep_quick.*`` with ``--quick``).

Examples::

    python -m experiments.bench_sweep --quick      # ~2 minutes on a shared 2-core machine
    python -m experiments.bench_sweep              # the full run
"""
from __future__ import annotations

import argparse
import datetime as _dt
import functools
import itertools
import json
import os
import platform
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan import build_fabric, sweep
from jaxplan.transport import FabricParams, fabric_of
from jaxplan.transport.spillage import SpillParams

RESULTS_DIR = Path(__file__).resolve().parent / "results"
TARGET_RATIO = 5.0


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _spec(args) -> dict:
    return {"random_scenes": {"seeds": list(range(args.scenes)), "shape": [args.size, args.size], "density": 0.4},
            "fabric": {"theta_tol_deg": args.thetas, "tau_h": args.taus},
            "spill": {"lam": args.lams},
            "metrics": {"top_sources": args.top_sources}}


def _interleaved_medians(fns: dict, repeats: int) -> dict:
    """Median seconds of each (compiled) ``fns[name]()``; the repeats are interleaved round-robin, so a
    burst of load from other jobs on the shared machine hits every method alike."""
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            start = time.perf_counter()
            jax.block_until_ready(fn())
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


def run(args) -> dict:
    spec = sweep.load_spec(_spec(args))
    settings = sweep.settings_of(spec)
    n = len(settings)
    fkeys = [k for k, _ in spec.fabric_grid]
    skeys = [k for k, _ in spec.spill_grid]
    scenes = [s for _, s in spec.scenes]
    h, w = scenes[0].shape
    max_steps = h + w + 1
    top = args.top_sources
    _, per_table = sweep.tables_of(spec)

    single = jax.jit(lambda scene, fp, sp: sweep.metrics_of(scene, fp, sp, top, max_steps))
    params = [(scenes[i], FabricParams(**dict(zip(fkeys, map(np.float32, f)))),
               SpillParams(**dict(zip(skeys, map(np.float32, s))))) for i, f, s in settings]
    tables = params[::per_table]
    build = jax.jit(fabric_of)
    after = jax.jit(lambda scene, fab, fp, sp: sweep.metrics_of(scene, fp, sp, top, max_steps,
                                                                fab=sweep.with_highways(fab, scene, fp)))
    plain = jax.jit(jax.vmap(lambda scene, fp, sp: sweep.metrics_of(scene, fp, sp, top, max_steps)))

    def loop():
        return [single(*p) for p in params]

    def loop_build():
        return [build_fabric(scene, fp) for scene, fp, _ in params]

    def loop_shared():
        fabs = [build(scene, fp) for scene, fp, _ in tables]
        return [after(p[0], fabs[j // per_table], p[1], p[2]) for j, p in enumerate(params)]

    def stacked(group):
        return jax.tree_util.tree_map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *group)

    compile_s = {}
    t0 = time.perf_counter()
    first = jax.block_until_ready(loop())
    compile_s["loop"] = time.perf_counter() - t0
    jax.block_until_ready(loop_build())
    t0 = time.perf_counter()
    shared = jax.block_until_ready(loop_shared())
    compile_s["loop_shared_table"] = time.perf_counter() - t0
    rounds = np.array([int(r["solver_rounds"]) for r in first])
    reference = np.array([float(r["top_delivered"]) for r in first])

    def diff(values) -> float:
        return float(np.max(np.abs(np.asarray(values, np.float64) - reference)))

    fns = {"loop": loop, "loop_build_fabric": loop_build, "loop_shared_table": loop_shared}
    results = {"loop": {"chunk": 1}, "loop_build_fabric": {"chunk": 1},
               "loop_shared_table": {"chunk": 1, "max_abs_diff_vs_loop": diff([r["top_delivered"] for r in shared])}}
    for key in ("loop", "loop_shared_table"):
        results[key]["compile_s"] = compile_s[key]
    for chunk in args.plain_chunks:   # vmap alone: one build_fabric per setting, chunks of `chunk` settings
        chunk = min(chunk, n)
        groups = [params[i:i + chunk] for i in range(0, n, chunk)]
        groups[-1] = groups[-1] + [groups[-1][-1]] * (chunk - len(groups[-1]))
        batches = [stacked(g) for g in groups]
        t0 = time.perf_counter()
        out = jax.block_until_ready([plain(*b) for b in batches])
        comp = time.perf_counter() - t0
        fns[f"vmap_plain_{chunk}"] = functools.partial(lambda bs: [plain(*b) for b in bs], batches)
        vals = np.concatenate([np.asarray(o["top_delivered"]) for o in out])[:n]
        results[f"vmap_plain_{chunk}"] = {"chunk": chunk, "compile_s": comp,
                                          "max_abs_diff_vs_loop": diff(vals),
                                          "rounds_run_per_chunk": [int(rounds[i:i + chunk].max())
                                                                   for i in range(0, n, chunk)]}
    for mode, tables_per_chunk in itertools.product(args.modes, args.chunks):   # the sweep's kernel
        budget = tables_per_chunk * sweep.bytes_per_table(scenes[0], None, per_table) / 2**20
        plans = sweep.plan_chunks(spec, settings, budget)
        t0 = time.perf_counter()
        out = [sweep.evaluate_chunk(p.chunk, mode) for p in plans]
        comp = time.perf_counter() - t0
        vals = np.concatenate([o["top_delivered"][:len(p.rows)] for o, p in zip(out, plans)])
        size = len(plans[0].chunk.scene_index)
        fns[f"sweep_{mode}_{size}"] = functools.partial(
            lambda ps, m: [sweep.evaluate_chunk(p.chunk, m) for p in ps], plans, mode)
        results[f"sweep_{mode}_{size}"] = {"chunk": size * per_table, "tables_per_chunk": size,
                                           "tables": mode, "chunks": len(plans), "compile_s": comp,
                                           "max_abs_diff_vs_loop": diff(vals)}
    for key, secs in _interleaved_medians(fns, args.repeats).items():
        results[key]["seconds"] = secs
    for _key, r in results.items():
        r["settings_per_s"] = n / r["seconds"]
    loop_rate = results["loop"]["settings_per_s"]
    shared_rate = results["loop_shared_table"]["settings_per_s"]
    for _key, r in results.items():
        r["ratio_vs_loop"] = r["settings_per_s"] / loop_rate
        r["ratio_vs_loop_shared_table"] = r["settings_per_s"] / shared_rate
    best = max((k for k in results if k.startswith("sweep_")), key=lambda k: results[k]["settings_per_s"])
    best_plain = max((k for k in results if k.startswith("vmap_plain_")),
                     key=lambda k: results[k]["settings_per_s"], default=None)
    return {
        "date": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "jax": jax.__version__, "backend": jax.default_backend(), "device": str(jax.devices()[0]),
        "cpu": _cpu_name(), "cpus_available": len(os.sched_getaffinity(0)),
        "shared_machine": True,
        "grid": [h, w], "settings": n, "tables": n // per_table, "settings_per_table": per_table,
        "scenes": args.scenes, "thetas": args.thetas, "taus": args.taus,
        "lams": args.lams, "top_sources": top, "repeats": args.repeats,
        "solver_rounds": {"min": int(rounds.min()), "median": float(np.median(rounds)), "max": int(rounds.max())},
        "results": results, "best": best, "best_ratio": results[best]["ratio_vs_loop"],
        "best_plain": best_plain,
        "best_plain_ratio": None if best_plain is None else results[best_plain]["ratio_vs_loop"],
        "target_ratio": TARGET_RATIO, "target_met": results[best]["ratio_vs_loop"] >= TARGET_RATIO,
    }


_NAMES = {"loop": "loop of jitted calls, one build_fabric + metrics per setting",
          "loop_build_fabric": "loop of jitted build_fabric alone (no metrics)",
          "loop_shared_table": "loop of jitted calls, one build_fabric per table + per-setting metrics"}


def markdown(res: dict, quick: bool) -> str:
    lines = [f"# Sweep benchmark{' (quick)' if quick else ''}", "",
             f"{res['date']}; jax {res['jax']} on {res['backend']} ({res['device']}); CPU: {res['cpu']}, "
             f"{res['cpus_available']} core(s) available. **Shared machine**: other jobs ran at the same time, so "
             "absolute times are noisy; the ratios are measured side by side in one run.", "",
             f"{res['settings']} settings on {res['grid'][0]}x{res['grid'][1]} random scenes (density 0.4): "
             f"{res['scenes']} scene(s) x theta_tol {res['thetas']} x tau_h {res['taus']} x spill lambda "
             f"{res['lams']}, i.e. {res['tables']} DP tables (scene x theta_tol) x {res['settings_per_table']} "
             f"settings sharing each; metrics of `jaxplan.sweep` (top_sources = {res['top_sources']}). Median of "
             f"{res['repeats']} passes over all settings, after compilation, the methods' passes interleaved. "
             "'max diff' is the largest difference of the top_delivered metric from the first loop (objects).", "",
             "| method | settings per call | settings/s | vs loop | vs shared-table loop | s per pass | "
             "compile s | max diff |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for key, r in res["results"].items():
        if key.startswith("vmap_plain_"):
            name = "vmapped chunks, one build_fabric per setting (vmap alone)"
        elif key.startswith("sweep_"):
            how = "lax.map" if r["tables"] == "map" else "vmap"
            name = (f"jaxplan.sweep chunks: {r['tables_per_chunk']} table(s) ({how}) x "
                    f"{res['settings_per_table']} settings (vmap)")
        else:
            name = _NAMES[key]
        comp = f"{r['compile_s']:.1f}" if "compile_s" in r else "-"
        md = f"{r['max_abs_diff_vs_loop']:.1e}" if "max_abs_diff_vs_loop" in r else "-"
        lines.append(f"| {name} | {r['chunk']} | {r['settings_per_s']:.1f} | {r['ratio_vs_loop']:.2f}x | "
                     f"{r['ratio_vs_loop_shared_table']:.2f}x | {r['seconds']:.3f} | {comp} | {md} |")
    sr = res["solver_rounds"]
    lines += ["", f"Solver rounds per setting: min {sr['min']}, median {sr['median']:g}, max {sr['max']} (a vmapped "
              "while loop runs until its slowest member converges).", "",
              f"Best sweep configuration: {res['best']} at {res['best_ratio']:.2f}x the loop of jitted calls; "
              f"target >= {res['target_ratio']:g}x: **{'met' if res['target_met'] else 'not met'}**."]
    if res["best_plain"] is not None:
        lines.append(f"vmap alone (no shared tables): {res['best_plain_ratio']:.2f}x the loop.")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m experiments.bench_sweep", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer settings and repeats")
    p.add_argument("--size", type=int, default=65)
    p.add_argument("--scenes", type=int, default=2)
    p.add_argument("--thetas", type=float, nargs="+", default=[45.0, 60.0])
    p.add_argument("--taus", type=float, nargs="+", default=[0.3, 0.4, 0.5, 0.6])
    p.add_argument("--lams", type=float, nargs="+", default=[0.0, 0.05, 0.1, 0.2])
    p.add_argument("--top-sources", type=int, default=4)
    p.add_argument("--chunks", type=int, nargs="+", default=[1, 4],
                   help="tables per chunk of the sweep's kernel (each with all its settings)")
    p.add_argument("--plain-chunks", type=int, nargs="+", default=[16],
                   help="settings per chunk of the vmap-alone variant")
    p.add_argument("--modes", nargs="+", default=["map", "vmap"], choices=["map", "vmap"],
                   help="how the sweep's kernel batches the tables of a chunk (sweep.evaluate_chunk's tables)")
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args(argv)
    if args.quick:
        args.scenes, args.taus, args.lams, args.repeats = 1, [0.3, 0.5], [0.0, 0.1], 3
        args.chunks, args.plain_chunks = [2], [4]
    res = run(args)
    text = markdown(res, args.quick)
    print(text)
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    name = "sweep_quick" if args.quick else "sweep"
    (RESULTS_DIR / f"{name}.json").write_text(json.dumps(res, indent=2) + "\n")
    (RESULTS_DIR / f"{name}.md").write_text(text)
    print(f"wrote {RESULTS_DIR / name}.json and .md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
