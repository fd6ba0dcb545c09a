"""MJX-JAX on the real PushAround scenes: compile time, peak memory and agreement with the C engine.

Issue 36, item 1. Each scene's MJX rollout runs in its own subprocess (so that its peak resident
memory, ``ru_maxrss``, is the rollout's alone): the world is built (declared contact pairs,
docs/physics.md), ``--batch`` candidate pushes are drawn (:func:`push_candidates`: the scene's
movables in turn, 8 world directions, one and two robots, 0.3 m/s for 2 s, those passing the
quick-pass), and ``simulate_pushes`` runs once: ``compile_s`` is the simulator's trace + XLA
compile (``Simulator.compile_seconds``), ``warm_s`` the rest of the call. The parent runs the same
candidates on the C engine and compares the verdicts (valid, wall hits) and every movable's final
pose (1 cm, 2 degrees).

Results: ``experiments/results/mjx_scale.{json,md}`` (``--stem`` to rename), and every candidate's
verdicts and final poses per engine in ``mjx_scale_outcomes.json.gz``.

Examples::

    python -m experiments.mjx_scale --scenes nominal:0 --batch 4          # smoke run
    python -m experiments.mjx_scale                                        # 3 nominal, dense, density x 64
    python -m experiments.mjx_scale --compile-only --stem mjx_scale_compile  # compile time and peak only
    python -m experiments.mjx_scale --rover 1 4 16 --stem mjx_rover        # rover, 64 / 256 / 1,024 particles

``--rover K ...``: the rover world of the ``default`` scene's 6 first routes with ``K`` particles
per object (64 particle bodies per unit of K), ``--batch`` routes (the 6 tiled) x ``--rover-ticks``
control ticks of 10 physics steps on MJX-JAX: compile time, peak memory and the run's time.
"""
from __future__ import annotations

import argparse
import gzip
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from jaxplan.transport.physics import check_routes, plan_routes, pursuit_policy, world_for_routes

ROOT = Path(__file__).resolve().parent.parent
RESULTS_DIR = Path(__file__).resolve().parent / "results"
SCENES = ("nominal:0", "nominal:1", "nominal:2", "dense:0", "density:0:45")
POSE_TOL = (0.01, np.deg2rad(2.0))   # m, rad


def make_scene(spec: str):
    """``nominal:SEED``, ``dense:SEED``, ``density:SEED:N`` or ``corridor:SEED`` -> PushScene."""
    from jaxplan.pusharound import corridor_scene, dense_scene, density_scene, nominal_scene

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
    from jaxplan.pusharound import direction_tasks, quick_pass, stack_tasks

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
            "poses": np.round(np.asarray(out.poses, np.float64), 5).tolist()}   # 10 um, 1e-5 rad


class Compiled(Exception):
    """Raised by :class:`CompileOnly` once the rollout is compiled."""


class CompileOnly:
    """A Simulator stand-in whose ``run`` compiles the rollout (``Simulator.compile``) and stops the
    caller with :class:`Compiled`: compile time and program size without the run."""

    def __init__(self, sim):
        self.sim = sim

    def __getattr__(self, name):
        return getattr(self.sim, name)

    def run(self, *args, **kwargs):
        self.sim.compile(*args, **kwargs)
        raise Compiled()


def child(spec: str, batch: int, backend: str, opt: str = "fast", compile_only: bool = False,
          sleep: bool = True) -> dict:
    """One engine's batched rollout in this process (the peak RSS is this run's). ``sleep``: the C
    engine's island sleeping (MJX has none)."""
    from jaxplan.pusharound import PushPhysicsConfig, build_push_world, make_push_simulator, simulate_pushes

    world = build_push_world(make_scene(spec), PushPhysicsConfig(sleep=sleep))
    tasks = push_candidates(world, batch)
    from jaxplan.physics import FAST_COMPILE

    sim = make_push_simulator(world, backend, compiler_options=FAST_COMPILE if opt == "fast" else None)
    if compile_only:   # trace + XLA compile of the batched rollout, no run
        try:
            simulate_pushes(world, tasks, sim=CompileOnly(sim))
        except Compiled:
            pass
        return {"scene": spec, "backend": backend, "batch": batch, "ticks": int(world.config.horizon),
                "compile_s": sim.compile_seconds, "xla": opt, "program_gb": _gb(sim.memory_bytes),
                "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20,
                "movables": len(world.scene.movables), "geoms": int(world.model.ngeom), "pairs": len(world.pairs),
                "meshes": int(world.mjx_model.nmesh)}
    t0 = time.perf_counter()
    out = simulate_pushes(world, tasks, sim=sim)
    cold = time.perf_counter() - t0
    compile_s = sim.compile_seconds
    print(f"{spec} {backend} B={batch}: cold {cold:.1f} s, compile {compile_s:.1f} s", file=sys.stderr, flush=True)
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20
    return {"scene": spec, "backend": backend, "batch": batch, "ticks": int(world.config.horizon),
            "cold_s": cold, "warm_s": cold - compile_s, "compile_s": compile_s, "peak_gb": peak_gb,
            "movables": len(world.scene.movables), "geoms": int(world.model.ngeom), "pairs": len(world.pairs),
            "meshes": int(world.mjx_model.nmesh), "outcome": _outcome_dict(out)}


def _gb(nbytes) -> float | None:
    return None if nbytes is None else nbytes / 2 ** 30


def rover_child(per_object: int, batch: int, ticks: int, opt: str, compile_only: bool = False) -> dict:
    """MJX-JAX's compile (and run, unless ``compile_only``) of the rover world with ``per_object``
    particles per object."""
    from experiments.bench_rover_throughput import tile_routes
    from jaxplan import builtin_scene
    from jaxplan.physics import FAST_COMPILE, Simulator
    from jaxplan.transport.physics import RoverConfig

    scene = builtin_scene("default")
    _, routes, _ = plan_routes(scene, n_routes=6)
    world = world_for_routes(scene, routes, RoverConfig(particles_per_object=per_object))
    sim = Simulator(world.model, pursuit_policy, substeps=world.config.substeps, bounds=world.bounds,
                    backend="mjx", compiler_options=FAST_COMPILE if opt == "fast" else None)
    row = {"per_object": per_object, "particles": world.n_particles, "batch": batch, "ticks": ticks,
           "geoms": int(world.model.ngeom), **world.caps, "xla": opt}
    t0 = time.perf_counter()
    try:
        chk = check_routes(scene, tile_routes(routes, batch), n_ticks=ticks, world=world,
                           simulator=CompileOnly(sim) if compile_only else sim)
        row.update(run_s=time.perf_counter() - t0 - sim.compile_seconds, finite=float(np.mean(chk.outcome.finite)))
    except Compiled:
        pass
    return {**row, "compile_s": sim.compile_seconds, "program_gb": _gb(sim.memory_bytes),
            "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20}


def _num(row: dict, key: str, fmt: str) -> str:
    return "" if row.get(key) is None else format(row[key], fmt)


def markdown_rover(rows: list, meta: dict) -> str:
    ran = "" if meta.get("compile_only") else f", run for {meta['rover_ticks']} control ticks of 10 physics steps"
    lines = [f"# MJX-JAX compile on the rover world ({meta['machine']})", "",
             f"The `default` scene's 6 first routes tiled to {meta['batch']} routes{ran}; compile = trace + XLA "
             "compile; program = the compiled program's buffers as XLA sizes them (arguments, outputs, "
             "temporaries); run = the rest of the call; peak = the subprocess's max RSS.", "",
             "| particles | geoms | max_geom_pairs | max_contact_points | compile s | program GB | run s | finite | "
             "peak GB |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['particles']} | | | | {r['error']} | | | | |")
        else:
            lines.append(f"| {r['particles']} | {r['geoms']} | {r['max_geom_pairs']} | {r['max_contact_points']} | "
                         f"{r['compile_s']:.1f} | {_num(r, 'program_gb', '.2f')} | {_num(r, 'run_s', '.1f')} | "
                         f"{_num(r, 'finite', '.2f')} | {r['peak_gb']:.2f} |")
    return "\n".join(lines) + "\n"


def _subprocess(cmd: list, timeout: float, failed: dict) -> dict:
    try:   # from the repository root, where ``experiments`` is importable
        proc = subprocess.run([sys.executable, "-m", "experiments.mjx_scale", *cmd], capture_output=True, text=True,
                              cwd=ROOT, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {**failed, "error": f"timed out after {timeout:.0f} s"}
    if proc.returncode != 0:
        return {**failed, "error": proc.stderr.strip().splitlines()[-1:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run_child(spec: str, batch: int, backend: str, timeout: float, xla: str = "fast",
              compile_only: bool = False) -> dict:
    cmd = ["--child", spec, "--batch", str(batch), "--backend", backend, "--xla", xla]
    cmd += ["--compile-only"] if compile_only else []
    return _subprocess(cmd, timeout, {"scene": spec, "backend": backend, "batch": batch})


def agreement(a: dict, b: dict) -> dict:
    """Verdicts and poses of outcome ``a`` (MJX) vs ``b`` (C): counts of candidates that differ."""
    pa, pb = np.asarray(a["poses"]), np.asarray(b["poses"])
    dxy = np.linalg.norm(pa[..., :2] - pb[..., :2], axis=-1).max(-1)
    dyaw = np.abs(np.angle(np.exp(1j * (pa[..., 2] - pb[..., 2])))).max(-1)
    pose_ok = (dxy <= POSE_TOL[0]) & (dyaw <= POSE_TOL[1])
    return {"valid_differ": int(np.sum(np.asarray(a["valid"]) != np.asarray(b["valid"]))),
            "hit_differ": int(np.sum(np.asarray(a["hit_fixed"]) != np.asarray(b["hit_fixed"]))),
            "pose_differ": int(np.sum(~pose_ok)), "max_dxy_m": float(dxy.max()),
            "median_dxy_m": float(np.median(dxy)), "median_dyaw_deg": float(np.rad2deg(np.median(dyaw))),
            "max_dyaw_deg": float(np.rad2deg(dyaw.max())), "n": int(len(pose_ok))}


def markdown(rows: list, meta: dict) -> str:
    lines = [f"# MJX-JAX on the PushAround scenes ({meta['machine']})", "",
             f"Batch {meta['batch']} candidates x {meta['ticks']} control ticks (6 physics steps each). Compile = "
             "trace + XLA compile, warm = the rest of the same call; peak = the MJX subprocess's max RSS. "
             "Agreement with the C engine: candidates whose "
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
    pairs = (("agreement", "MJX-JAX vs C"), ("agreement_no_sleep", "MJX-JAX vs C, sleeping off"),
             ("c_sleep_vs_no_sleep", "C vs C, sleeping off"))
    if any(key in r for r in rows for key, _ in pairs[1:]):
        lines += ["", "Per comparison (candidates out of the batch; a movable's pose error is the largest over the "
                  "scene's movables):", "",
                  "| scene | comparison | valid differ | hit differ | pose differ | median dxy m | max dxy m | "
                  "median dyaw deg | max dyaw deg |", "|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            for key, label in pairs:
                ag = r.get(key)
                if ag:
                    lines.append(f"| {r['scene']} | {label} | {ag['valid_differ']} | {ag['hit_differ']} | "
                                 f"{ag['pose_differ']} | {ag['median_dxy_m']:.4f} | {ag['max_dxy_m']:.4f} | "
                                 f"{ag['median_dyaw_deg']:.2f} | {ag['max_dyaw_deg']:.2f} |")
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
    ap = argparse.ArgumentParser(prog="python -m experiments.mjx_scale", description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--backend", default="mjx")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per MJX subprocess")
    ap.add_argument("--xla", choices=("fast", "default"), default="fast",
                    help="MJX compile: FAST_COMPILE options (LLVM's expensive passes off) or XLA's defaults")
    ap.add_argument("--compile-only", action="store_true",
                    help="MJX: trace and compile the batched rollout, no run (compile time and peak memory only)")
    ap.add_argument("--rover", type=int, nargs="+", default=None, metavar="K",
                    help="the rover world instead, with K particles per object (1 4 16: 64 / 256 / 1,024 particles)")
    ap.add_argument("--rover-ticks", type=int, default=20, help="rover control ticks per rollout")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--rover-child", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    ap.add_argument("--stem", default="mjx_scale")
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child, args.batch, args.backend, args.xla, args.compile_only)))
        return {}
    if args.rover_child:
        print(json.dumps(rover_child(args.rover_child, args.batch, args.rover_ticks, args.xla, args.compile_only)))
        return {}
    from experiments.results_io import write_results

    rows = []
    meta = {"machine": f"{platform.machine()}, {os.cpu_count()} cores", "batch": args.batch, "ticks": 80,
            "backend": args.backend, "xla": args.xla}
    if args.rover:
        meta.update(rover_ticks=args.rover_ticks, compile_only=args.compile_only)
        for k in args.rover:
            cmd = ["--rover-child", str(k), "--batch", str(args.batch), "--rover-ticks", str(args.rover_ticks),
                   "--xla", args.xla] + (["--compile-only"] if args.compile_only else [])
            rows.append(_subprocess(cmd, args.timeout, {"per_object": k, "particles": 64 * k}))
            print(json.dumps(rows[-1]), flush=True)
            write_results(args.results_dir, args.stem, {"meta": meta, "rows": rows}, markdown_rover(rows, meta))
        return {"meta": meta, "rows": rows}
    outcomes = {}   # per scene and engine: verdicts and final poses of every candidate
    for spec in args.scenes:
        mj = run_child(spec, args.batch, args.backend, args.timeout, args.xla, args.compile_only)
        if args.compile_only:
            rows.append({"scene": spec, "mjx": mj})
            print(json.dumps(rows[-1]), flush=True)
            write_results(args.results_dir, args.stem, {"meta": meta, "rows": rows}, markdown_compile(rows, meta))
            continue
        c = child(spec, args.batch, "c")
        awake = child(spec, args.batch, "c", sleep=False)
        row = {"scene": spec, "mjx": {k: v for k, v in mj.items() if k != "outcome"},
               "c": {k: v for k, v in c.items() if k not in ("outcome", "peak_gb")}}
        outcomes[spec] = {"mjx": mj.get("outcome"), "c": c["outcome"], "c_no_sleep": awake["outcome"]}
        if "outcome" in mj:
            row["agreement"] = agreement(mj["outcome"], c["outcome"])
            row["agreement_no_sleep"] = agreement(mj["outcome"], awake["outcome"])
        row["c_sleep_vs_no_sleep"] = agreement(c["outcome"], awake["outcome"])
        rows.append(row)
        print(json.dumps(row), flush=True)
        write_results(args.results_dir, args.stem, {"meta": meta, "rows": rows}, markdown(rows, meta))
        with gzip.open(args.results_dir / f"{args.stem}_outcomes.json.gz", "wt") as f:
            json.dump(outcomes, f)
    return {"meta": meta, "rows": rows}


if __name__ == "__main__":
    main()
