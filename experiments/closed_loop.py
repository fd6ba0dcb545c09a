"""Episodes closed through physics on held-out scenes: does the plan's prediction track MuJoCo?

On scenes of held-out seeds of ``experiments/spill_data.py`` (never in a spill-model fit), an episode
plans on the grid, pushes each route with the MuJoCo rover (C engine), rasterises the particles back
and re-plans (``jaxplan.transport.physics.closed_loop``), ``--pushes`` pushes at most. Per scene:
the cumulative delivered mass of physics against the sum of the grid's per-push predictions (each
made from the counts physics left), after which pushes the two lie within 10%, and a grid-only
episode beside them. Writes ``experiments/results/closed_loop.{json,md}``, one figure per scene and
the first scene's GIF.

    python -m experiments.closed_loop                        # 3 held-out scenes, 15 pushes each
    python -m experiments.closed_loop --pushes 3 --scenes 1  # a quick look
"""
from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np

from experiments.results_io import write_results
from experiments.spill_data import family_scene, is_heldout
from jaxplan.transport.spillage import ROVER_MODELS

# one scene per family with enough material for 15 pushes; seeds 3, 7 and 11 are held out
SCENES = (("uniform", 0.35, 3), ("piles", 0.35, 7), ("strips", 0.35, 11))
WITHIN = 0.10


def run_scene(family: str, density: float, seed: int, pushes: int, spill_model: str, out_dir: Path,
              gif: bool) -> dict:
    import matplotlib.pyplot as plt

    from jaxplan.transport.physics import (
        animate_closed_loop,
        grid_episode,
        plot_closed_loop,
        run_closed_loop,
    )

    spill = ROVER_MODELS[spill_model]
    scene = family_scene(family, density, seed)
    start = time.perf_counter()
    loop = run_closed_loop(scene, spill=spill, max_pushes=pushes, progress=True)
    grid_only = grid_episode(scene, spill=spill, max_pushes=pushes)
    rel = loop.relative_error
    name = scene.name
    fig = plot_closed_loop(loop, grid_only, title=f"{name}: physics against the plan")
    fig.savefig(out_dir / f"closed_loop_{name}.png", dpi=100)
    plt.close(fig)
    if gif:
        animate_closed_loop(scene, loop, out_dir / f"closed_loop_{name}.gif", fps=6, dpi=60)
    return {"scene": name, "heldout": is_heldout(seed), "pushes": len(loop.pushes), "stop_reason": loop.stop_reason,
            "physics": [round(float(x), 2) for x in loop.delivered],
            "predicted": [round(float(x), 2) for x in loop.predicted],
            "grid_only": [round(float(x), 2) for x in grid_only],
            "relative_error": [round(float(x), 4) for x in rel],
            "within_after": int(np.sum(rel <= WITHIN)), "within_every_push": bool(np.all(rel <= WITHIN)),
            "spilled": round(sum(p["spilled"] for p in loop.pushes), 1),
            "left_behind": round(sum(p["left_behind"] for p in loop.pushes), 1),
            "seconds": round(time.perf_counter() - start, 1)}


def markdown(result: dict) -> str:
    lines = ["# Episodes closed through physics, held-out scenes", "",
             f"{result['pushes']} pushes at most per scene; spill model `{result['spill_model']}`; C engine. "
             "'predicted' sums the grid's prediction of each push from the counts physics left; "
             "'grid-only' is the episode pushed on the grid alone.", "",
             "| scene | pushes | physics delivered | predicted | grid-only | within 10% after | worst rel. error | "
             "spilled / left behind (physics) |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in result["rows"]:
        worst = max(r["relative_error"]) if r["relative_error"] else 0.0
        lines.append(f"| {r['scene']} | {r['pushes']} | {r['physics'][-1]:.0f} | {r['predicted'][-1]:.1f} | "
                     f"{r['grid_only'][-1]:.1f} | {r['within_after']} of {r['pushes']} | {worst:.1%} | "
                     f"{r['spilled']:.0f} / {r['left_behind']:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m experiments.closed_loop", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="examples:\n  python -m experiments.closed_loop\n"
                                            "  python -m experiments.closed_loop --pushes 3 --scenes 1")
    parser.add_argument("--pushes", type=int, default=15, help="push budget per scene; default 15")
    parser.add_argument("--scenes", type=int, default=len(SCENES), help=f"how many of the {len(SCENES)} scenes")
    parser.add_argument("--spill-model", default="learned", choices=tuple(ROVER_MODELS))
    parser.add_argument("--results-dir", type=Path, default=Path("experiments/results"))
    parser.add_argument("--stem", default="closed_loop")
    parser.add_argument("--no-gif", action="store_true")
    args = parser.parse_args(argv)
    if args.pushes < 1:
        parser.error(f"--pushes: must be >= 1; got {args.pushes}")
    if not 1 <= args.scenes <= len(SCENES):
        parser.error(f"--scenes: must lie in [1, {len(SCENES)}]; got {args.scenes}")
    args.results_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for k, (family, density, seed) in enumerate(SCENES[: args.scenes]):
        rows.append(run_scene(family, density, seed, args.pushes, args.spill_model, args.results_dir,
                              gif=k == 0 and not args.no_gif))
    result = {"pushes": args.pushes, "spill_model": args.spill_model, "rows": rows, "machine": platform.platform()}
    write_results(args.results_dir, args.stem, result, markdown(result))
    return result


if __name__ == "__main__":
    main()
