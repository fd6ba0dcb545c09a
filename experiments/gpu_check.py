"""One GPU check: the physics engines' throughput and the fabric's GPU rows, in under 8 minutes.

Issue 36, item 3. On the machine at hand (named in the results) it measures

- PushAround: candidates per second on the nominal scene (``--push-scene``), ``--push-batch``
  candidate pushes (64, the search's batch; ``experiments/mjx_scale.push_candidates``) x 80 control
  ticks, per engine: cold call (MJX: trace + compile) and the median of ``--repeats`` warm calls;
- the rover with gravel: route-steps per second (routes x ticks x substeps / warm physics time) at
  batch ``--batches`` (64 / 256 / 1,024 routes, ``bench_rover_throughput.measure_engine``), per engine;
- the fabric benchmark's GPU rows: ``build_fabric`` on random ``--fabric-sizes`` grids
  (``bench_fabric.time_jax``: one warm-up call, then the median of ``--repeats``).

Engines: ``c`` (MuJoCo C, every core), ``mjx`` (MJX-JAX), ``warp`` (MJX-Warp; skipped when warp-lang
is not installed). A measurement is not started once ``--budget-s`` has passed (default 420 s), so
the whole run ends within about 8 minutes; skipped rows say so. Results are written after every
row: ``experiments/results/gpu_check.{json,md}`` (``--stem`` to rename).

Examples::

    python -m experiments.gpu_check                       # on a GPU machine
    python -m experiments.gpu_check --tiny --engines c    # CPU smoke run (seconds)
"""
from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from jaxplan.transport.physics import plan_routes, world_for_routes

ROOT = Path(__file__).resolve().parent.parent
RESULTS_DIR = Path(__file__).resolve().parent / "results"


def device_name() -> str:
    import jax

    d = jax.devices()[0]
    return f"{d.platform}: {getattr(d, 'device_kind', str(d))}, {os.cpu_count()} CPU cores"


def push_row(spec: str, batch: int, engine: str, repeats: int) -> dict:
    from experiments.mjx_scale import make_scene, push_candidates
    from jaxplan.pusharound import build_push_world, make_push_simulator, simulate_pushes

    world = build_push_world(make_scene(spec))
    tasks = push_candidates(world, batch)
    sim = make_push_simulator(world, engine)
    t0 = time.perf_counter()
    simulate_pushes(world, tasks, sim=sim)
    cold = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = simulate_pushes(world, tasks, sim=sim)
        warm.append(time.perf_counter() - t0)
    w = float(np.median(warm))
    return {"part": "pusharound", "scene": spec, "engine": engine, "batch": batch, "cold_s": cold, "warm_s": w,
            "per_s": batch / w, "unit": "candidates/s", "valid": int(np.sum(out.valid))}


def rover_rows(scene_name: str, n_routes: int, batches, engines, ticks: int, repeats: int, room) -> list:
    from experiments.bench_rover import small_scene
    from experiments.bench_rover_throughput import measure_engine, tile_routes
    from jaxplan import builtin_scene
    from jaxplan.transport.physics import RoverConfig

    if not room():
        return [{"part": "rover", "engine": e, "batch": b, "skipped": "time budget"} for b in batches for e in engines]
    scene = small_scene() if scene_name == "small" else builtin_scene(scene_name)
    _, routes, _ = plan_routes(scene, n_routes=n_routes)
    world = world_for_routes(scene, routes, RoverConfig())
    sub = world.config.substeps
    rows = []
    for b in batches:
        for e in engines:
            if not room():
                rows.append({"part": "rover", "engine": e, "batch": b, "skipped": "time budget"})
                continue
            m = measure_engine(scene, tile_routes(routes, b), world, e, ticks, repeats)
            rows.append({"part": "rover", "scene": scene_name, "engine": e, "batch": b, "cold_s": m["cold_s"],
                         "warm_s": m["physics_median_s"], "per_s": b * m["ticks"] * sub / m["physics_median_s"],
                         "unit": "route-steps/s", "particles": int(world.n_particles), "ticks": m["ticks"]})
            print(f"rover {e} B={b}: {rows[-1]['per_s']:,.0f} route-steps/s", flush=True)
    return rows


def fabric_rows(sizes, repeats: int, room) -> list:
    from experiments.bench_fabric import make_scene, time_jax
    from jaxplan import FabricParams

    rows = []
    for n in sizes:
        if not room():
            rows.append({"part": "fabric", "n": n, "skipped": "time budget"})
            continue
        t0 = time.perf_counter()
        _, times = time_jax(make_scene(n, 0.4, 0), FabricParams(), repeats)
        rows.append({"part": "fabric", "n": n, "ms": float(np.median(times)),
                     "first_call_s": time.perf_counter() - t0 - sum(times) / 1e3})
    return rows


def markdown(result: dict) -> str:
    lines = [f"# GPU check: {result['device']}", "",
             f"Budget {result['budget_s']:.0f} s; took {result['elapsed_s']:.0f} s. Warm = median of "
             f"{result['repeats']} calls after a cold one (MJX: trace + compile).", "",
             "| part | scene | engine | batch | cold s | warm s | throughput |", "|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        if r["part"] == "fabric":
            cell = r.get("skipped") or f"{r['ms']:.1f} ms per fabric"
            lines.append(f"| fabric | {r['n']}x{r['n']}, density 0.4 | JAX | 1 | "
                         f"{r.get('first_call_s', float('nan')):.1f} | | {cell} |")
        elif "skipped" in r or "error" in r:
            lines.append(f"| {r['part']} | {r.get('scene', '')} | {r['engine']} | {r['batch']} | | | "
                         f"{r.get('skipped') or r.get('error')} |")
        else:
            lines.append(f"| {r['part']} | {r['scene']} | {r['engine']} | {r['batch']} | {r['cold_s']:.1f} | "
                         f"{r['warm_s']:.2f} | {r['per_s']:,.0f} {r['unit']} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m experiments.gpu_check", description=__doc__.split("\n")[0])
    ap.add_argument("--engines", nargs="+", default=["c", "mjx", "warp"], choices=["c", "mjx", "warp"])
    ap.add_argument("--push-scene", default="nominal:0")
    ap.add_argument("--push-batch", type=int, default=64)
    ap.add_argument("--rover-scene", default="default")
    ap.add_argument("--routes", type=int, default=6, help="distinct rover routes tiled to each batch")
    ap.add_argument("--batches", type=int, nargs="+", default=[64, 256, 1024])
    ap.add_argument("--ticks", type=int, default=100, help="rover control ticks per rollout")
    ap.add_argument("--fabric-sizes", type=int, nargs="*", default=[65, 256, 1024])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--budget-s", type=float, default=420.0)
    ap.add_argument("--tiny", action="store_true",
                    help="CPU smoke run: corridor push scene x 2, small rover scene, batch 2, 4 ticks, fabric 25")
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    ap.add_argument("--stem", default="gpu_check")
    args = ap.parse_args(argv)
    if args.tiny:
        args.push_scene, args.push_batch, args.rover_scene, args.routes = "corridor:0", 2, "small", 2
        args.batches, args.ticks, args.fabric_sizes, args.repeats = [2], 4, [25], 1
    from experiments.results_io import write_results
    from jaxplan.physics import warp_available

    engines = [e for e in args.engines if e != "warp" or warp_available()]
    t_start = time.perf_counter()

    def room() -> bool:
        return time.perf_counter() - t_start < args.budget_s

    result = {"device": device_name(), "platform": platform.platform(), "budget_s": args.budget_s,
              "repeats": args.repeats, "engines": engines, "rows": []}
    if "warp" in args.engines and "warp" not in engines:
        result["rows"].append({"part": "all", "engine": "warp", "batch": "", "skipped": "warp-lang not installed"})

    def save():
        result["elapsed_s"] = time.perf_counter() - t_start
        write_results(args.results_dir, args.stem, result, markdown(result))

    for e in engines:
        if not room():
            result["rows"].append({"part": "pusharound", "engine": e, "batch": args.push_batch,
                                   "skipped": "time budget"})
            continue
        try:
            result["rows"].append(push_row(args.push_scene, args.push_batch, e, args.repeats))
        except Exception as exc:   # a failing engine is a result, the rest still run
            result["rows"].append({"part": "pusharound", "engine": e, "batch": args.push_batch,
                                   "error": f"{type(exc).__name__}: {exc}"[:200]})
        save()
    result["rows"] += rover_rows(args.rover_scene, args.routes, args.batches, engines, args.ticks, args.repeats, room)
    save()
    result["rows"] += fabric_rows(args.fabric_sizes, args.repeats, room)
    save()
    return result


if __name__ == "__main__":
    main()
