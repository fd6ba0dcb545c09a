"""Neighbour reads on the padded flat layout against the per-direction shift, for two grid stencils.

The measurement behind ``_grid.pad_flat``: the look-back heatmap (``heatmap.heat``) and the
successor steps (``visibility.feasible_successors``) as they are now (on ``_grid.padded_rows``)
and as they were (each neighbour read by ``_grid.shift``, a pad and a slice per direction; kept
here as the peer). On Table 2's scenes (``bench_fabric.make_scene``, density 0.4, after one push)
both run jitted in one process, alternating, ``--rounds`` calls each; the script checks that they
agree exactly first. Compiled as the library compiles them (``_compile.grid_jit``: XLA's older
emitters up to 65^2). Writes ``experiments/results/stencil_ab.{json,md}``.

    python -m experiments.stencil_ab                    # 65 and 256
    taskset -c 0 python -m experiments.stencil_ab       # pinned to one core, as the paper's runs
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

if __package__ in (None, ""):   # run as a script: make ``experiments`` importable
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from experiments._results import write_results  # noqa: E402
from experiments.bench_fabric import RESULTS_DIR, make_scene, stamp  # noqa: E402


def _heat_by_shift(psi, occupied, heading, hop_len, target, cell_size):
    """``heatmap.heat`` as it was: each direction's scores moved onto X by ``_grid.shift``."""
    import jax.numpy as jnp

    from jaxplan import _grid, heatmap

    mass = heatmap._source_mass(psi, occupied, hop_len)
    best = jnp.zeros_like(psi)
    for d, (dr, dc) in enumerate(_grid.DIRS):
        score = heatmap._look_back(d, mass, heading[..., 0], heading[..., 1], hop_len, cell_size)
        best = jnp.maximum(best, _grid.shift(score, -dr, -dc, 0.0))
    return jnp.where(target, 0.0, best)


def _feasible_by_shift(occupied, goal, dist, tvec, theta_tol_deg, monotone, cell_size):
    """``visibility.feasible_successors`` as it was: neighbours read by ``_grid.neighbours``."""
    import jax.numpy as jnp

    from jaxplan import _grid, visibility

    in_grid = jnp.asarray(_grid.in_grid(occupied.shape))
    nb_dist = _grid.neighbours(dist, jnp.inf) if monotone else None
    return in_grid & visibility.step_feasible(
        occupied[None], _grid.neighbours(occupied | goal, False), visibility.cone_alignment(tvec), dist[None],
        nb_dist, visibility.cone_cos(theta_tol_deg), monotone, cell_size)


def _alternating_us(fns: dict, rounds: int) -> dict:
    import jax

    for fn in fns.values():
        jax.block_until_ready(fn())
    times = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            start = time.perf_counter()
            jax.block_until_ready(fn())
            times[name].append((time.perf_counter() - start) * 1e6)
    return {name: statistics.median(t) for name, t in times.items()}


def measure(n: int, rounds: int) -> dict:
    import jax
    import numpy as np

    from experiments.table2 import _best_route
    from jaxplan import FabricParams, SpillParams, build_fabric, execute, heatmap, visibility
    from jaxplan._compile import grid_jit

    params = FabricParams()
    scene = make_scene(n, 0.4, 0)
    scene = scene.with_obj(execute.quantize(scene.obj))
    fabric = build_fabric(scene, params)
    route, _ = jax.jit(_best_route, static_argnums=2)(scene, fabric, 8 * n)
    scene = scene.with_obj(execute.execute_jit(scene, route, SpillParams(lam=0.05))[0])
    fabric = build_fabric(scene, params)
    occupied = ~scene.target_mask & (scene.obj > 0)
    hop_len = np.linalg.norm(np.asarray(fabric.heading), axis=-1) * float(scene.cell_size)
    heat_args = (fabric.psi, fabric.occupied, fabric.heading, hop_len, scene.target_mask, scene.cell_size)
    feasible_args = (occupied, scene.target_mask, scene.dist, scene.tvec, params.theta_tol_deg)
    kernels = {
        "heat": (grid_jit(heatmap.heat), grid_jit(_heat_by_shift), heat_args),
        "feasible_successors": (grid_jit(visibility.feasible_successors, static_argnums=5),
                                grid_jit(_feasible_by_shift, static_argnums=5), feasible_args + (True, scene.cell_size)),
    }
    row = {"n": n}
    for name, (flat, by_shift, args) in kernels.items():
        if not np.array_equal(np.asarray(flat(*args)), np.asarray(by_shift(*args))):
            raise SystemExit(f"stencil_ab: {name} differs between the layouts at {n}^2")
        us = _alternating_us({"flat": lambda f=flat, a=args: f(*a), "shift": lambda f=by_shift, a=args: f(*a)}, rounds)
        row[name] = {"flat_us": us["flat"], "shift_us": us["shift"], "speedup": us["shift"] / us["flat"]}
    return row


def markdown(result) -> str:
    env = result["environment"]
    lines = ["# Grid stencils: padded flat layout vs per-direction shift", "",
             f"{env['cpu_model']}, {env['cpus_available']} cores available, jax {env['jax_version']}; "
             f"{result['date']}. Median of {result['rounds']} alternating calls each, one process, "
             "after one push on a density-0.4 scene; equal outputs checked.", "",
             "| grid | kernel | padded flat us | shift us | speedup |", "|---|---|---|---|---|"]
    for row in result["rows"]:
        for name in ("heat", "feasible_successors"):
            k = row[name]
            lines.append(f"| {row['n']}^2 | {name} | {k['flat_us']:.1f} | {k['shift_us']:.1f} | {k['speedup']:.2f}x |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[65, 256])
    p.add_argument("--rounds", type=int, default=300, help="alternating calls of each layout")
    p.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = p.parse_args(argv)
    rows = [measure(n, args.rounds) for n in args.sizes]
    result = {**stamp(), "rounds": args.rounds, "rows": rows}
    write_results(args.results_dir, "stencil_ab", result, markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
