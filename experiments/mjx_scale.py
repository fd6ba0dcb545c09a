"""MJX-JAX on the real PushAround scenes: compile time, peak memory and agreement with the C engine.

Issue 36, item 1. Each scene's MJX rollout runs in its own subprocess (so that its peak resident
memory, ``ru_maxrss``, is the rollout's alone): the world is built (declared contact pairs,
docs/physics.md), ``--batch`` candidate pushes are drawn (:func:`push_candidates`: the scene's
movables in turn, 8 world directions, one and two robots, 0.3 m/s for 2 s, those passing the
quick-pass), and ``simulate_pushes`` runs cold (trace + XLA compile + run) and warm (run).
``compile_s`` = cold - warm. The parent runs the same candidates on the C engine and compares the
verdicts (valid, wall hits) and every movable's final pose (1 cm, 2 degrees).

Results: ``experiments/results/mjx_scale.{json,md}`` (``--stem`` to rename).

Examples::

    python experiments/mjx_scale.py --scenes nominal:0 --batch 4          # smoke run
    python experiments/mjx_scale.py                                        # 3 nominal, dense, density x 64
    python experiments/mjx_scale.py --compile-only --stem mjx_scale_compile  # compile time and peak only
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS_DIR = Path(__file__).resolve().parent / "results"
SCENES = ("nominal:0", "nominal:1", "nominal:2", "dense:0", "density:0:45")
POSE_TOL = (0.01, np.deg2rad(2.0))   # m, rad


def make_scene(spec: str):
    """``nominal:SEED``, ``dense:SEED``, ``density:SEED:N`` or ``corridor:SEED`` -> PushScene."""
    from jaxplan.pusharound.scenarios import corridor_scene, dense_scene, density_scene, nominal_scene

    kind, *args = spec.split(":")
    if kind == "nominal":
        return nominal_scene(int(args[0]))
    if kind == "corridor":
        return corridor_scene(int(args[0]))
    if kind == "dense":
        return dense_scene(int(args[0]))
    if kind == "density":
        return density_scene(int(args[0]), int(args[1]))
    raise ValueError(f"scene: expected nominal:SEED, dense:SEED or density:SEED:N; got {spec!r}.")


def push_candidates(world, n: int, speed: float = 0.3, duration: float = 2.0):
    """``n`` candidate pushes (a batched PushTask): every movable in turn, 8 world directions, teams
    of 1 and 2, kept when they pass the quick-pass; cycled when fewer pass."""
    from jaxplan.pusharound.push import direction_tasks, quick_pass, stack_tasks

    tasks = []
    for m in range(len(world.scene.movables)):
        tasks += direction_tasks(world, m, np.arange(8) * np.pi / 4, speed, duration)
    batch = stack_tasks(tasks)
    ok = np.concatenate([s + np.nonzero(quick_pass(world, type(batch)(*(np.asarray(f)[s:s + 64] for f in batch))).ok)[0]
                         for s in range(0, len(tasks), 64)])
    idx = ok if len(ok) else np.arange(len(tasks))
    # interleave movables: candidate k from movable k mod M where possible
    by_mov = {}
    for i in idx:
        by_mov.setdefault(int(batch.movable[i]), []).append(int(i))
    order = []
    while len(order) < len(idx):
        for lst in by_mov.values():
            if lst:
                order.append(lst.pop(0))
    pick = [order[k % len(order)] for k in range(n)]
    return type(batch)(*(np.asarray(f)[pick] for f in batch))


def _outcome_dict(out) -> dict:
    return {"valid": out.valid.tolist(), "hit_fixed": out.hit_fixed.tolist(), "finite": out.finite.tolist(),
            "poses": np.asarray(out.poses).tolist()}


class _Compiled(Exception):
    pass


def child(spec: str, batch: int, backend: str, opt: str = "fast", compile_only: bool = False) -> dict:
    """One engine's cold and warm batched rollout in this process (the peak RSS is this run's)."""
    from jaxplan.pusharound.physics import build_push_world
    from jaxplan.pusharound.push import make_push_simulator, simulate_pushes

    world = build_push_world(make_scene(spec))
    tasks = push_candidates(world, batch)
    from jaxplan.physics.rollout import FAST_COMPILE

    sim = make_push_simulator(world, backend, compiler_options=FAST_COMPILE if opt == "fast" else None)
    if compile_only:   # trace + XLA compile of the batched rollout, no run
        timing = {}

        def lower_only(qpos0, qvel0, params, pstate0, n_ticks, fields):
            import jax.numpy as jnp

            fn = sim._mjx_fn(n_ticks, ())
            t0 = time.perf_counter()
            fn.lower(jnp.asarray(qpos0, jnp.float32), jnp.asarray(qvel0, jnp.float32), params, pstate0,
                     {}).compile()
            timing["compile_s"] = time.perf_counter() - t0
            raise _Compiled()

        sim._run_mjx = lower_only
        try:
            simulate_pushes(world, tasks, sim=sim)
        except _Compiled:
            pass
        return {"scene": spec, "backend": backend, "batch": batch, "ticks": int(world.config.horizon),
                "compile_s": timing["compile_s"], "xla": opt,
                "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20,
                "movables": len(world.scene.movables), "geoms": int(world.model.ngeom), "pairs": len(world.pairs),
                "meshes": int(world.mjx_model.nmesh)}
    t0 = time.perf_counter()
    simulate_pushes(world, tasks, sim=sim)
    cold = time.perf_counter() - t0
    print(f"{spec} {backend} B={batch}: cold {cold:.1f} s", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    out = simulate_pushes(world, tasks, sim=sim)
    warm = time.perf_counter() - t0
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20
    return {"scene": spec, "backend": backend, "batch": batch, "ticks": int(world.config.horizon),
            "cold_s": cold, "warm_s": warm, "compile_s": max(cold - warm, 0.0), "peak_gb": peak_gb,
            "movables": len(world.scene.movables), "geoms": int(world.model.ngeom), "pairs": len(world.pairs),
            "meshes": int(world.mjx_model.nmesh), "outcome": _outcome_dict(out)}


def run_child(spec: str, batch: int, backend: str, timeout: float, xla: str = "fast",
              compile_only: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, __file__, "--child", spec, "--batch", str(batch), "--backend", backend, "--xla", xla]
    cmd += ["--compile-only"] if compile_only else []
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"scene": spec, "backend": backend, "batch": batch, "error": f"timed out after {timeout:.0f} s"}
    if proc.returncode != 0:
        return {"scene": spec, "backend": backend, "batch": batch, "error": proc.stderr.strip().splitlines()[-1:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def agreement(a: dict, b: dict) -> dict:
    """Verdicts and poses of outcome ``a`` (MJX) vs ``b`` (C): counts of candidates that differ."""
    pa, pb = np.asarray(a["poses"]), np.asarray(b["poses"])
    dxy = np.linalg.norm(pa[..., :2] - pb[..., :2], axis=-1).max(-1)
    dyaw = np.abs(np.angle(np.exp(1j * (pa[..., 2] - pb[..., 2])))).max(-1)
    pose_ok = (dxy <= POSE_TOL[0]) & (dyaw <= POSE_TOL[1])
    return {"valid_differ": int(np.sum(np.asarray(a["valid"]) != np.asarray(b["valid"]))),
            "hit_differ": int(np.sum(np.asarray(a["hit_fixed"]) != np.asarray(b["hit_fixed"]))),
            "pose_differ": int(np.sum(~pose_ok)), "max_dxy_m": float(dxy.max()),
            "max_dyaw_deg": float(np.rad2deg(dyaw.max())), "n": int(len(pose_ok))}


def markdown(rows: list, meta: dict) -> str:
    lines = [f"# MJX-JAX on the PushAround scenes ({meta['machine']})", "",
             f"Batch {meta['batch']} candidates x {meta['ticks']} control ticks (6 physics steps each). Compile = "
             "cold - warm call; peak = the MJX subprocess's max RSS. Agreement with the C engine: candidates whose "
             "valid / wall-hit verdict differs, and whose final movable poses differ by more than 1 cm or 2 deg.", "",
             "| scene | movables | geoms | declared pairs | meshes | MJX compile s | MJX warm s | peak GB | "
             "C warm s | valid differ | hit differ | pose differ | max dxy m | max dyaw deg |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        m, c, ag = r.get("mjx", {}), r.get("c", {}), r.get("agreement", {})
        if "error" in m:
            lines.append(f"| {r['scene']} | | | | | {m['error']} | | | | | | | | |")
            continue
        lines.append(f"| {r['scene']} | {m['movables']} | {m['geoms']} | {m['pairs']} | {m['meshes']} | "
                     f"{m['compile_s']:.1f} | {m['warm_s']:.2f} | {m['peak_gb']:.2f} | "
                     f"{c.get('warm_s', float('nan')):.2f} | "
                     f"{ag.get('valid_differ', '')} | {ag.get('hit_differ', '')} | {ag.get('pose_differ', '')} | "
                     f"{ag.get('max_dxy_m', float('nan')):.4f} | {ag.get('max_dyaw_deg', float('nan')):.2f} |")
    return "\n".join(lines) + "\n"


def markdown_compile(rows: list, meta: dict) -> str:
    lines = [f"# MJX-JAX compile on the PushAround scenes ({meta['machine']})", "",
             f"Trace + XLA compile of the batched rollout ({meta['batch']} candidates x {meta['ticks']} control "
             "ticks), no run; peak = the subprocess's max RSS.", "",
             "| scene | movables | geoms | declared pairs | meshes | compile s | peak GB |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        m = r["mjx"]
        if "error" in m:
            lines.append(f"| {r['scene']} | | | | | {m['error']} | |")
        else:
            lines.append(f"| {r['scene']} | {m['movables']} | {m['geoms']} | {m['pairs']} | {m['meshes']} | "
                         f"{m['compile_s']:.1f} | {m['peak_gb']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--backend", default="mjx")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per MJX subprocess")
    ap.add_argument("--xla", choices=("fast", "default"), default="fast",
                    help="MJX compile: FAST_COMPILE options (LLVM's expensive passes off) or XLA's defaults")
    ap.add_argument("--compile-only", action="store_true",
                    help="MJX: trace and compile the batched rollout, no run (compile time and peak memory only)")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    ap.add_argument("--stem", default="mjx_scale")
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child, args.batch, args.backend, args.xla, args.compile_only)))
        return {}
    sys.path.insert(0, str(ROOT))
    from experiments._results import write_results

    rows = []
    meta = {"machine": f"{platform.machine()}, {os.cpu_count()} cores", "batch": args.batch, "ticks": 80,
            "backend": args.backend, "xla": args.xla}
    for spec in args.scenes:
        mj = run_child(spec, args.batch, args.backend, args.timeout, args.xla, args.compile_only)
        if args.compile_only:
            rows.append({"scene": spec, "mjx": mj})
            print(json.dumps(rows[-1]), flush=True)
            write_results(args.results_dir, args.stem, {"meta": meta, "rows": rows}, markdown_compile(rows, meta))
            continue
        c = child(spec, args.batch, "c")
        row = {"scene": spec, "mjx": {k: v for k, v in mj.items() if k != "outcome"},
               "c": {k: v for k, v in c.items() if k not in ("outcome", "peak_gb")}}
        if "outcome" in mj:
            row["agreement"] = agreement(mj["outcome"], c["outcome"])
        rows.append(row)
        print(json.dumps(row), flush=True)
        write_results(args.results_dir, args.stem, {"meta": meta, "rows": rows}, markdown(rows, meta))
    return {"meta": meta, "rows": rows}


if __name__ == "__main__":
    main()
