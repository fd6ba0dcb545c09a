"""Pushes per second: a batch of episodes as one vmapped, scanned program against the host loop.

The batch runs ``episode.rollout_scenes_jit`` (``reset`` then ``max_pushes`` steps of ``step`` in one
``jax.lax.scan``, ``vmap``-ed over the scenes; full rebuild) on ``--batch`` random scenes
(``sweep.random_scene``, seeds 0..B-1) of one shape. The host loop runs ``run_episode(rebuild="full")``
on the same scenes one after the other. Both must give the same pushes (sources, modes, pushes per
episode, delivered mass per push to 1e-3 objects); the table says whether they do.

Timing. Batch: the first call compiles; compile time = the first call's wall time minus the median of
the ``--repeats`` timed calls that follow, and only those timed calls enter the rate. Host loop: one
untimed episode first (it compiles the loop's programs), then every episode once, timed as a whole;
the first episode's wall time is reported apart. Rate = valid pushes / seconds. ``--walk-cap`` sets
the batch's static walk length (default ``episode.default_walk_cap``; the host loop keeps its own cap
and retry); ``--also-walk-cap N`` adds a second batch row with that cap. Writes
``experiments/results/episode.{json,md}``.

    python -m experiments.bench_episode                      # 64 episodes, 32x32, 30 pushes
    python -m experiments.bench_episode --also-walk-cap 64   # plus a batch walked 64 steps at most
    python -m experiments.bench_episode --quick              # 4 episodes, 12x12, 4 pushes
"""
from __future__ import annotations

import argparse
import datetime as _dt
import os
import platform
import statistics
import time
from pathlib import Path

import jax
import numpy as np

from experiments.results_io import write_results
from jaxplan import FabricParams, SpillParams, build_fabric, random_scene, run_episode
from jaxplan.transport import (
    STOP_REASONS,
    EpisodeParams,
    act,
    default_walk_cap,
    reset,
    rollout_scenes_jit,
    stack_scenes,
)

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def _host(scenes, params, spill, episode):
    """``(episodes, first_episode_s, total_s)``: one untimed warm-up episode, then all timed."""
    start = time.perf_counter()
    run_episode(scenes[0], params, spill, episode)
    first = time.perf_counter() - start
    start = time.perf_counter()
    episodes = [run_episode(s, params, spill, episode) for s in scenes]
    return episodes, first, time.perf_counter() - start


def _batch(stacked, params, spill, episode, walk_cap, repeats):
    """``(records, final, first_call_s, timed_s list)`` of the vmapped, scanned program."""
    def call():
        return jax.block_until_ready(rollout_scenes_jit(stacked, params, spill, episode, episode.max_pushes,
                                                        walk_cap=walk_cap))

    start = time.perf_counter()
    _, final, records = call()
    first = time.perf_counter() - start
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        runs.append(time.perf_counter() - start)
    return jax.device_get(records), jax.device_get(final), first, runs


def _breakdown(stacked, params, spill, episode, walk_cap, repeats) -> dict:
    """Milliseconds per batch step of its two parts, each jitted and vmapped alone on the first
    state: ``act`` (plan, push, bookkeeping) and the full build."""
    def median_ms(fn, *args):
        jax.block_until_ready(fn(*args))   # compiles
        runs = []
        for _ in range(max(repeats, 3)):
            start = time.perf_counter()
            jax.block_until_ready(fn(*args))
            runs.append((time.perf_counter() - start) * 1e3)
        return statistics.median(runs)

    states = jax.jit(jax.vmap(lambda s: reset(s, params, spill, episode)))(stacked)
    act_ms = median_ms(jax.jit(jax.vmap(lambda st: act(st, params, spill, episode, walk_cap=walk_cap)[:2])), states)
    build_ms = median_ms(jax.jit(jax.vmap(lambda s: build_fabric(s, params))), states.scene)
    return {"walk_cap": walk_cap, "act_ms": act_ms, "build_ms": build_ms}


def _compare(records, final, episodes) -> list[str]:
    """Differences between the batch and the host loop, one line per episode that differs."""
    out = []
    for b, ep in enumerate(episodes):
        n = ep.n_pushes
        valid = records.valid[b]
        problems = []
        if int(valid.sum()) != n or not valid[:n].all():
            problems.append(f"{int(valid.sum())} pushes vs {n}")
        else:
            if not np.array_equal(records.source[b, :n], ep.source):
                problems.append("sources")
            if not np.array_equal(records.mode[b, :n], ep.mode):
                problems.append("modes")
            if not np.allclose(records.push_delivered[b, :n], ep.push_delivered, atol=1e-3, rtol=1e-5):
                problems.append("delivered")
        reason = STOP_REASONS[int(final.stop[b])]
        if reason != ep.stop_reason:
            problems.append(f"stop {reason} vs {ep.stop_reason}")
        if problems:
            out.append(f"episode {b}: " + ", ".join(problems))
    return out


def measure(batch: int, side: int, max_pushes: int, density: float, lam: float, walk_caps, repeats: int,
            breakdown: bool = True) -> dict:
    scenes = [random_scene(seed, (side, side), density) for seed in range(batch)]
    params, spill = FabricParams(), SpillParams(lam=lam)
    episode = EpisodeParams(max_pushes=max_pushes, rebuild="full")
    stacked = stack_scenes(scenes)
    rows = []
    for cap in walk_caps:
        records, final, first, runs = _batch(stacked, params, spill, episode, cap, repeats)
        steady = statistics.median(runs)
        pushes = int(records.valid.sum())
        rows.append({"walk_cap": cap, "pushes": pushes, "first_call_s": first, "timed_s": runs, "median_s": steady,
                     "compile_s": first - steady, "pushes_per_s": pushes / steady, "records": records, "final": final})
        print(f"batch, walk cap {cap}: {pushes} pushes in {steady:.3f} s ({pushes / steady:.0f}/s); "
              f"compile ~{first - steady:.1f} s", flush=True)
    parts = _breakdown(stacked, params, spill, episode, walk_caps[-1], repeats) if breakdown else None
    episodes, host_first, host_total = _host(scenes, params, spill, episode)
    host_pushes = sum(e.n_pushes for e in episodes)
    host_rate = host_pushes / host_total
    print(f"host loop: {host_pushes} pushes in {host_total:.3f} s ({host_rate:.0f}/s); first episode "
          f"{host_first:.1f} s", flush=True)
    ms = lambda key: float(np.median(np.concatenate([getattr(e, key) for e in episodes])))  # noqa: E731
    for row in rows:
        row["mismatches"] = _compare(row.pop("records"), row.pop("final"), episodes)
        row["same_pushes"] = not row["mismatches"]
        row["ratio"] = row["pushes_per_s"] / host_rate
    return {"batch": batch, "shape": [side, side], "max_pushes": max_pushes, "density": density, "lam": lam,
            "repeats": repeats, "default_walk_cap": default_walk_cap((side, side)), "batched": rows,
            "breakdown": parts,
            "host": {"pushes": host_pushes, "total_s": host_total, "pushes_per_s": host_rate,
                     "first_episode_s": host_first, "median_plan_ms": ms("plan_ms"),
                     "median_execute_ms": ms("execute_ms"), "median_rebuild_ms": ms("rebuild_ms"),
                     "stop_reasons": sorted({e.stop_reason for e in episodes})}}


def markdown(result: dict) -> str:
    h = result["host"]
    lines = ["# Episodes as one vmapped, scanned program vs the host loop", "",
             f"{result['date']}, {result['host_machine']} ({result['cpus']} CPUs), jax {result['jax']} "
             f"({result['backend']}). {result['batch']} random scenes of {result['shape'][0]}x{result['shape'][1]} "
             f"(density {result['density']}, spill lambda {result['lam']}), up to {result['max_pushes']} pushes each, "
             "full rebuild. Batch: median of "
             f"{result['repeats']} calls of the compiled program; compile = first call minus that median, not in "
             "the rate. Host loop: `run_episode` on every scene once, after one untimed warm-up episode.", "",
             "| run | walk cap | pushes | seconds | pushes/s | vs host loop | compile s | same pushes |",
             "|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in result["batched"]:
        lines.append(f"| vmap + scan | {r['walk_cap']} | {r['pushes']} | {r['median_s']:.3f} | "
                     f"{r['pushes_per_s']:.0f} | {r['ratio']:.2f}x | {r['compile_s']:.1f} | {r['same_pushes']} |")
    lines.append(f"| host loop | {result['default_walk_cap']} (+retry) | {h['pushes']} | {h['total_s']:.3f} | "
                 f"{h['pushes_per_s']:.0f} | 1.00x | ({h['first_episode_s']:.1f} s first episode) | |")
    lines += ["", f"Host loop per push (medians): plan {h['median_plan_ms']:.2f} ms, execute "
              f"{h['median_execute_ms']:.2f} ms, rebuild {h['median_rebuild_ms']:.2f} ms; the rest of its "
              f"{1e3 / h['pushes_per_s']:.2f} ms per push is the host's own work (reads, dispatch, Python).",
              f"Stop reasons: {', '.join(h['stop_reasons'])}."]
    parts = result.get("breakdown")
    if parts:
        b = result["batch"]
        host_ms = 1e3 / h["pushes_per_s"]
        lines += ["", "Where a batch step's time goes (each part jitted and vmapped alone on the first state, "
                  f"walk cap {parts['walk_cap']}): `act` (plan, push, bookkeeping) {parts['act_ms']:.1f} ms and "
                  "the full build "
                  f"{parts['build_ms']:.1f} ms for {b} episodes, i.e. {parts['act_ms'] / b:.2f} and "
                  f"{parts['build_ms'] / b:.2f} ms per episode, against the host loop's plan + execute "
                  f"{h['median_plan_ms'] + h['median_execute_ms']:.2f} ms and rebuild {h['median_rebuild_ms']:.2f} ms "
                  f"per push. Batching removes the host's own work and shares planning's many small sequential "
                  f"operations (walks, splines) across episodes; the build gains "
                  f"{h['median_rebuild_ms'] / (parts['build_ms'] / b):.2f}x from it, so even with a free `act` the "
                  f"batch could not exceed {host_ms / (parts['build_ms'] / b):.1f}x the host loop's {host_ms:.2f} ms "
                  "per push."]
    for r in result["batched"]:
        for m in r["mismatches"]:
            lines.append(f"- walk cap {r['walk_cap']}: {m}")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.bench_episode", description=__doc__.split("\n")[0],
                                 epilog="example: python -m experiments.bench_episode "
                                        "--batch 64 --side 32 --max-pushes 30 --also-walk-cap 64",
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, default=None,
                    help="episodes (random scenes, seeds 0..B-1; default 64, --quick 4)")
    ap.add_argument("--side", type=int, default=None, help="grid side N for N x N scenes (default 32, --quick 12)")
    ap.add_argument("--max-pushes", type=int, default=None, help="push budget per episode (default 30, --quick 4)")
    ap.add_argument("--density", type=float, default=0.4, help="occupied fraction of the scenes (default 0.4)")
    ap.add_argument("--lam", type=float, default=0.05, help="spill lambda (default 0.05)")
    ap.add_argument("--walk-cap", type=int, default=None,
                    help="static walk length of the batch (default episode.default_walk_cap)")
    ap.add_argument("--also-walk-cap", type=int, default=None, metavar="N", help="a second batch row walked N steps")
    ap.add_argument("--repeats", type=int, default=None,
                    help="timed calls of the compiled batch (default 3, --quick 1)")
    ap.add_argument("--quick", action="store_true",
                    help="a tiny run (defaults 4 episodes, 12x12, 4 pushes, 1 repeat; explicit options win)")
    ap.add_argument("--no-breakdown", action="store_true", help="skip timing act and the build apart")
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = ap.parse_args(argv)
    for key, full, quick in (("batch", 64, 4), ("side", 32, 12), ("max_pushes", 30, 4), ("repeats", 3, 1)):
        if getattr(args, key) is None:
            setattr(args, key, quick if args.quick else full)
    if args.batch < 1 or args.side < 4 or args.max_pushes < 1 or args.repeats < 1 or not 0 < args.density <= 1:
        ap.error("--batch, --max-pushes, --repeats must be >= 1, --side >= 4 and --density in (0, 1]")
    caps = [default_walk_cap((args.side, args.side)) if args.walk_cap is None else args.walk_cap]
    if args.also_walk_cap is not None and args.also_walk_cap not in caps:
        caps.append(args.also_walk_cap)
    result = measure(args.batch, args.side, args.max_pushes, args.density, args.lam, caps, args.repeats,
                     breakdown=not args.no_breakdown)
    result = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "host_machine": platform.platform(),
              "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
              "jax": jax.__version__, "backend": jax.default_backend(), **result}
    write_results(args.results_dir, "episode", result, markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
