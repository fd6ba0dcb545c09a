"""Where the fabric's time goes: each stage of ``build_fabric`` jitted and timed on its own.

Stages: successor graph (visibility), policy iteration (P*), K-best table levels (sidetracks), the
first-hop / psi / heatmap / highway tail, and the whole ``build_fabric`` for comparison, with the
default policy solver and with the plain wavefront solver (same result, one round per hop). Uses the
benchmark's scenes (uniform random counts, central circle target). Prints a markdown table and
writes ``experiments/results/fabric_profile.json``.

    .venv/bin/python -m experiments.profile_fabric --sizes 65 256 --density 0.4
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan import FabricParams, _kbest, fabric, heatmap, visibility
from experiments.bench_fabric import make_scene


def _median_ms(fn, *args, repeats: int) -> float:
    jax.block_until_ready(fn(*args))                      # compile and warm up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append((time.perf_counter() - start) * 1e3)
    return float(np.median(times))


def profile(n: int, density: float, seed: int, k: int, repeats: int) -> dict:
    scene = make_scene(n, density, seed)
    params = FabricParams(k=k, solver="policy")
    occupied = ~scene.target_mask & (scene.obj > 0)
    max_rounds = params.resolved_max_hops(scene.shape)

    graph_fn = jax.jit(lambda sc: visibility.successor_graph(
        sc.obj, occupied, sc.target_mask, sc.dist, sc.tvec, params.theta_tol_deg, sc.cell_size, True))
    graph = graph_fn(scene)
    policy_fn = jax.jit(lambda g: _kbest.best_paths(g, occupied, scene.cell_size, max_rounds))
    best_raw, best_len, policy, iterations = policy_fn(graph)
    kbest_fn = jax.jit(lambda r, l, p, g: _kbest.kbest_tables(r, l, p, g, occupied, k, scene.cell_size))
    built = fabric.build_fabric(scene, params)

    def tail(fab):
        path_next = jnp.where((fab.table.next_dir[..., 0] >= 0) & (fab.table.next_dir[..., 0] < 8),
                              fab.table.next_dir[..., 0], -1)
        psi = heatmap.propagated_mass(fab.value, fab.occupied, path_next, max_rounds)
        _, heading, hop_len = fabric.first_hops(fab.table, scene.tvec, scene.cell_size)
        heat = heatmap.heat(psi, fab.occupied, heading, hop_len, scene.target_mask, scene.cell_size)
        return psi, heat, heatmap.highways(heat, scene.target_mask, params.tau_h)

    return {
        "grid": n, "density": density, "seed": seed, "k": k, "policy_iterations": int(iterations),
        "graph_ms": _median_ms(graph_fn, scene, repeats=repeats),
        "policy_iteration_ms": _median_ms(policy_fn, graph, repeats=repeats),
        "kbest_levels_ms": _median_ms(kbest_fn, best_raw, best_len, policy, graph, repeats=repeats),
        "first_hop_psi_heat_highways_ms": _median_ms(jax.jit(tail), built, repeats=repeats),
        "build_fabric_ms": _median_ms(fabric.build_fabric, scene, params, repeats=repeats),
        "wavefront_rounds": int(fabric.build_fabric(scene, params.replace(solver="wavefront")).rounds),
        "wavefront_build_fabric_ms": _median_ms(fabric.build_fabric, scene, params.replace(solver="wavefront"),
                                                repeats=repeats),
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[65, 256], help="grid sides")
    parser.add_argument("--density", type=float, default=0.4, help="fraction of cells holding objects")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--k", type=int, nargs="+", default=[1, 4], help="continuation-table depths")
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per stage (median)")
    parser.add_argument("--out", default="experiments/results/fabric_profile.json")
    args = parser.parse_args(argv)

    rows = [profile(n, args.density, args.seed, k, args.repeats) for n in args.sizes for k in args.k]
    keys = ("graph_ms", "policy_iteration_ms", "kbest_levels_ms", "first_hop_psi_heat_highways_ms", "build_fabric_ms",
            "wavefront_build_fabric_ms")
    lines = [f"| grid | K | PI iterations | wavefront rounds | {' | '.join(keys)} |",
             "|---|---:|---:|---:|" + "---:|" * len(keys)]
    lines += [f"| {r['grid']}x{r['grid']} | {r['k']} | {r['policy_iterations']} | {r['wavefront_rounds']} | "
              + " | ".join(f"{r[key]:.2f}" for key in keys) + " |" for r in rows]
    table = "\n".join(lines)
    print(table)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"jax": jax.__version__, "density": args.density, "rows": rows}, indent=2))
    out.with_suffix(".md").write_text(f"# Fabric stage profile (density {args.density}, median ms)\n\n{table}\n")
    print(f"wrote {out} and {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
