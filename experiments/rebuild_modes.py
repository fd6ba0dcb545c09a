"""Whole episodes with the selective and the full rebuild, side by side, on the built-in scenes and
on random grids of chosen sizes.

``EpisodeParams(rebuild="auto")`` rebuilds in full on CPU grids under ``SELECTIVE_MIN_CELLS`` cells
and selectively from there (``episode.rebuild_mode``). This measures what the rule decides: each
scene's episode runs ``--repeats`` times with each rebuild, alternating, and reports the median
rebuild time per tick (first tick excluded: it compiles), whether both rebuilds ran the same
episode (sources and delivered mass per tick), and which one ``auto`` picks. Writes
``experiments/results/rebuild_modes.{json,md}``. ``--random N ...`` adds random N x N grids
(``bench_fabric.make_scene``: the paper's protocol, density ``--density``, seed 0), named ``randomN``,
to place the threshold between the built-in scenes' sizes.

    python -m experiments.rebuild_modes
    python -m experiments.rebuild_modes --scenes default sparse65 --repeats 3
    python -m experiments.rebuild_modes --random 35 40 45 50 55
"""
from __future__ import annotations

import argparse
import datetime as _dt
import platform
import statistics
from pathlib import Path

import jax
import numpy as np

from experiments.results_io import write_results
from jaxplan import BUILTIN_SCENES, builtin_scene, run_episode
from jaxplan.transport import SELECTIVE_MIN_CELLS, EpisodeParams, rebuild_mode
from jaxplan.transport.spillage import SpillParams

RESULTS_DIR = Path(__file__).resolve().parent / "results"
MODES = ("selective", "full")


def _scene(name: str, density: float):
    if name.startswith("random"):
        from experiments.bench_fabric import make_scene

        return make_scene(int(name[len("random"):]), density, 0)
    return builtin_scene(name)


def measure(name: str, repeats: int, max_pushes: int, lam: float, density: float = 0.4) -> dict:
    scene = _scene(name, density)
    per_tick = {m: [] for m in MODES}
    episodes = {}
    for _ in range(repeats):
        for mode in MODES:   # alternate, so drifts of the machine hit both alike
            ep = run_episode(scene, spill=SpillParams(lam=lam),
                             episode=EpisodeParams(max_pushes=max_pushes, rebuild=mode))
            per_tick[mode].append(float(np.median(ep.rebuild_ms[1:])) if ep.n_pushes > 1 else float("nan"))
            episodes[mode] = ep
    same = (np.array_equal(episodes["selective"].source, episodes["full"].source)
            and np.array_equal(episodes["selective"].delivered, episodes["full"].delivered))
    return {"scene": name, "shape": list(scene.shape), "cells": int(np.prod(scene.shape)),
            "pushes": episodes["full"].n_pushes, "auto": rebuild_mode("auto", scene.shape),
            "rebuild_ms": {m: per_tick[m] for m in MODES},
            "median_rebuild_ms": {m: statistics.median(per_tick[m]) for m in MODES}, "same_episode": bool(same)}


def markdown(result: dict) -> str:
    lines = ["# Selective vs full rebuild in whole episodes", "",
             f"{result['date']}, {result['host']}, jax {result['jax']} ({result['backend']}). Median rebuild time per "
             f"tick (first tick excluded), each episode run {result['repeats']} times per rebuild, alternating; "
             f"`auto` = `episode.rebuild_mode` (full below {SELECTIVE_MIN_CELLS} cells on a CPU).", "",
             "| scene | grid | pushes | selective ms (runs) | full ms (runs) | full / selective | auto picks "
             "| same episode |",
             "|---|---|---:|---|---|---:|---|---|"]
    for r in result["scenes"]:
        sel, full = r["median_rebuild_ms"]["selective"], r["median_rebuild_ms"]["full"]
        runs = lambda m: ", ".join(f"{x:.2f}" for x in r["rebuild_ms"][m])  # noqa: E731
        lines.append(f"| {r['scene']} | {r['shape'][0]}x{r['shape'][1]} | {r['pushes']} "
                     f"| {sel:.2f} ({runs('selective')}) | "
                     f"{full:.2f} ({runs('full')}) | {full / sel:.2f} | {r['auto']} | {r['same_episode']} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.rebuild_modes", description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="+", default=list(BUILTIN_SCENES), choices=list(BUILTIN_SCENES))
    ap.add_argument("--repeats", type=int, default=2, help="episodes per scene and rebuild (default 2)")
    ap.add_argument("--max-pushes", type=int, default=30, help="push budget per episode (default 30)")
    ap.add_argument("--lam", type=float, default=0.05, help="spill lambda (default 0.05)")
    ap.add_argument("--random", type=int, nargs="*", default=[], metavar="N",
                    help="also random N x N grids (bench_fabric.make_scene, seed 0), e.g. 35 40 45 50 55")
    ap.add_argument("--density", type=float, default=0.4, help="density of the random grids (default 0.4)")
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.max_pushes < 2:
        ap.error("--repeats must be >= 1 and --max-pushes >= 2")
    if any(n < 4 for n in args.random) or not 0.0 < args.density <= 1.0:
        ap.error("--random sizes must be >= 4 and --density in (0, 1]")
    scenes = []
    for name in [*args.scenes, *(f"random{n}" for n in args.random)]:
        scenes.append(measure(name, args.repeats, args.max_pushes, args.lam, args.density))
        r = scenes[-1]
        print(f"{name}: selective {r['median_rebuild_ms']['selective']:.2f} ms, "
              f"full {r['median_rebuild_ms']['full']:.2f} ms "
              f"per tick, auto -> {r['auto']}, same episode {r['same_episode']}", flush=True)
    result = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "host": platform.platform(),
              "jax": jax.__version__, "backend": jax.default_backend(), "repeats": args.repeats,
              "max_pushes": args.max_pushes, "lam": args.lam, "random_density": args.density, "scenes": scenes}
    # a run too short to time (one push) is NaN: kept as json writes it
    write_results(args.results_dir, "rebuild_modes", result, markdown(result), allow_nan=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
