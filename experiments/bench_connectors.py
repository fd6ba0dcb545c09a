"""Connector planning after a push: ``plan_connectors`` from scratch vs ``refresh_connectors``.

Per grid (``make_scene`` of bench_fabric, density 0.4, seed 0; counts rounded to ``execute.QUANTUM``):
build the fabric and its connectors, push the best source's route (lam 0.05), selectively rebuild,
then time, side by side on the grid after the push, ``plan_connectors`` and ``refresh_connectors``
(one warm-up each, then the median of ``--repeats`` calls ending in ``block_until_ready``), and check
the two give the same anchors. Writes ``experiments/results/connectors.{json,md}``.

    python -m experiments.bench_connectors --sizes 25 65 128
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

from experiments.bench_fabric import RESULTS_DIR, environment, make_scene


def run(n: int, repeats: int) -> dict:
    import jax
    import jax.numpy as jnp

    from jaxplan import FabricParams, SpillParams, build_fabric, extract_paths, plan_connectors
    from jaxplan.core import timed
    from jaxplan.transport import execute_jit, quantize, refresh_connectors, routes_from_paths, selective_rebuild

    params = FabricParams()
    scene = make_scene(n, 0.4, 0)
    scene = scene.with_obj(quantize(scene.obj))
    fabric = build_fabric(scene, params)
    old = plan_connectors(scene, params, fabric)
    source = jnp.stack(jnp.unravel_index(jnp.argmax(fabric.value), scene.shape))[None]
    route = jax.tree.map(lambda a: a[0],
                         routes_from_paths(scene, extract_paths(fabric, source, max_steps=8 * n)))
    new_obj, push = execute_jit(scene, route, SpillParams(lam=0.05))
    after = scene.with_obj(new_obj)
    rebuilt, _ = selective_rebuild(after, params, fabric, push.changed)

    def plan():
        return plan_connectors(after, params, rebuilt)

    def refresh():
        return refresh_connectors(after, params, rebuilt, fabric, old, push.changed)

    out = {"n": n}
    for name, fn in (("plan_ms", plan), ("refresh_ms", refresh)):
        timed(fn)
        out[name] = statistics.median(timed(fn)[1] for _ in range(repeats))
    planned, (refreshed, reused) = plan(), refresh()
    out["same_anchors"] = bool(np.array_equal(np.asarray(planned.anchor), np.asarray(refreshed.anchor)))
    out["anchors"] = int(np.sum(np.asarray(planned.anchors) >= 0))
    out["reused"] = int(np.sum(np.asarray(reused)))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m experiments.bench_connectors", description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[25, 65, 128])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = p.parse_args(argv)
    rows = [run(n, args.repeats) for n in args.sizes]
    env = environment(False)
    lines = ["# Connectors after a push", "", f"{env['cpu_model']}, {env['cpus_available']} cores, jax "
             f"{env['jax_version']}; {env['timestamp']}. Median of {args.repeats} warm calls.", "",
             "| grid | plan_connectors ms | refresh_connectors ms | anchors | reused | same anchors |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {r['n']}x{r['n']} | {r['plan_ms']:.1f} | {r['refresh_ms']:.1f} | {r['anchors']} | {r['reused']} | "
              f"{'yes' if r['same_anchors'] else 'NO'} |" for r in rows]
    text = "\n".join(lines) + "\n"
    args.results_dir.mkdir(parents=True, exist_ok=True)
    (args.results_dir / "connectors.json").write_text(json.dumps({"environment": env, "rows": rows}, indent=2) + "\n")
    (args.results_dir / "connectors.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
