"""Whole episodes with and without ``EpisodeParams(reselect=True)`` on the built-in scenes.

With ``reselect`` every tick applies Eq. 6 (delivered mass under the spill model) to every source before
planning, so headings, psi, the heatmap, highways and anchors follow the selected routes (the paper's
Section 3.3); without it they follow the raw-count optimum (Eq. 5) and only the pushed Deliver route
is chosen by Eq. 6. Same scene, fabric and spill parameters for both; reports delivered, spilled,
remaining, pushes, distance driven and the median planning time per tick (which includes the
reselection; the first tick's compilation is excluded by the median).

Then, side by side on each scene's first fabric and at the episode's walk length, one reselection
call both ways: ``selection.reselect`` (only sources with two or more candidates are evaluated) and
``selection.reselect_jit`` (every entry of every cell, one program): median wall time of
``--repeats`` interleaved warm calls each, and whether the two fabrics are identical. Writes
``experiments/results/reselect_episodes.{json,md}``.

    python -m experiments.reselect_episodes                      # the four built-in scenes
    python -m experiments.reselect_episodes --scenes default --lam 0.3
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import platform
import statistics
import time
from pathlib import Path

import jax
import numpy as np

from jaxplan import BUILTIN_SCENES, FabricParams, build_fabric, builtin_scene, run_episode
from jaxplan.transport import EpisodeParams, default_walk_cap, reselect, reselect_jit
from jaxplan.transport.spillage import SpillParams

RESULTS_DIR = Path(__file__).resolve().parent / "results"
COLUMNS = ("delivered", "spilled", "remaining", "pushes", "driven", "median_plan_ms", "stop_reason")


def run(scene_name: str, reselect: bool, lam: float, max_pushes: int) -> dict:
    scene = builtin_scene(scene_name)
    episode = run_episode(scene, FabricParams(), SpillParams(lam=lam),
                          EpisodeParams(reselect=reselect, max_pushes=max_pushes), progress=True)
    totals = episode.totals()
    return {"scene": scene_name, "reselect": reselect, "initial_mass": totals["initial_mass"],
            **{c: totals[c] for c in COLUMNS}}


def _call_ms(fn) -> float:
    start = time.perf_counter()
    jax.block_until_ready(fn())
    return (time.perf_counter() - start) * 1e3


def one_call(scene_name: str, lam: float, repeats: int) -> dict:
    """One reselection of the scene's first fabric, compact vs every entry (module docstring)."""
    scene, params, spill = builtin_scene(scene_name), FabricParams(), SpillParams(lam=lam)
    fabric = build_fabric(scene, params)
    walk = default_walk_cap(scene.shape)
    compact = lambda: reselect(scene, params, fabric, spill, max_steps=walk)  # noqa: E731
    every = lambda: reselect_jit(scene, params, fabric, spill, max_steps=walk)  # noqa: E731
    same = all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(jax.tree.leaves(compact()),
                                                                            jax.tree.leaves(every())))
    times = [(_call_ms(compact), _call_ms(every)) for _ in range(repeats)]
    compact_ms, every_ms = (statistics.median(t[i] for t in times) for i in (0, 1))
    return {"scene": scene_name, "walk": walk, "compact_ms": compact_ms, "every_entry_ms": every_ms,
            "ratio": every_ms / compact_ms, "identical": same}


def markdown(rows: list, calls: list, args) -> str:
    lines = ["# Episodes with and without Eq. 6 reselection of every source", "",
             f"{_dt.datetime.now(_dt.UTC):%Y-%m-%d %H:%M} UTC; {platform.machine()}, jax {jax.__version__} "
             f"on {jax.default_backend()}; spill lam {args.lam}, push budget {args.max_pushes}; default FabricParams.",
             "", "Masses in objects; driven in world units; plan ms = median per tick, reselection included.", "",
             "| scene | reselect | initial | delivered | spilled | remaining | pushes | driven | plan ms | stop |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {'yes' if r['reselect'] else 'no'} | {r['initial_mass']:.1f} | "
                     f"{r['delivered']:.1f} | {r['spilled']:.1f} | {r['remaining']:.1f} | {r['pushes']} | "
                     f"{r['driven']:.0f} | {r['median_plan_ms']:.1f} | {r['stop_reason']} |")
    lines += ["", f"One reselection of each scene's first fabric (median of {args.repeats} interleaved warm calls):",
              "",
              "| scene | walk steps | compact ms | every entry ms | every / compact | identical fabrics |",
              "|---|---:|---:|---:|---:|---|"]
    for c in calls:
        lines.append(f"| {c['scene']} | {c['walk']} | {c['compact_ms']:.1f} | {c['every_entry_ms']:.1f} | "
                     f"{c['ratio']:.0f}x | {'yes' if c['identical'] else 'NO'} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.reselect_episodes", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=list(BUILTIN_SCENES), choices=BUILTIN_SCENES)
    parser.add_argument("--lam", type=float, default=SpillParams().lam, help="spill per radian of turning")
    parser.add_argument("--max-pushes", type=int, default=200, help="push budget per episode")
    parser.add_argument("--repeats", type=int, default=3, help="warm calls per way in the one-call comparison")
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = parser.parse_args(argv)
    rows = [run(name, reselect, args.lam, args.max_pushes) for name in args.scenes for reselect in (False, True)]
    calls = [one_call(name, args.lam, args.repeats) for name in args.scenes]
    args.results_dir.mkdir(parents=True, exist_ok=True)
    meta = {"lam": args.lam, "max_pushes": args.max_pushes, "jax": jax.__version__, "backend": jax.default_backend(),
            "utc": f"{_dt.datetime.now(_dt.UTC):%Y-%m-%dT%H:%M:%SZ}"}
    (args.results_dir / "reselect_episodes.json").write_text(
        json.dumps({"meta": meta, "rows": rows, "one_call": calls}, indent=1, default=float))
    table = markdown(rows, calls, args)
    (args.results_dir / "reselect_episodes.md").write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
