"""The selective update and the full build of two commits, in alternating processes on one machine.

On a machine whose speed drifts between runs, two Table 2 runs compare machines as much as code;
this compares code. Each commit is checked out into a temporary git worktree; then, ``--pairs``
times, a fresh process of the base commit and one of the head commit each push Table 2's routes
on 65^2 scenes (``bench_fabric.make_scene``, densities 0.2 / 0.4 / 0.6, seed 0, ``--ticks`` pushes
each) and time, after every push, the selective update and the full build (``--repeats`` calls
each, median). A process reports the median over its pushes. Both commits need Table 2's route
picking (``experiments.table2._best_route``, from 2026-12-01 on). Writes
``experiments/results/rebuild_ab.{json,md}``.

    python -m experiments.rebuild_ab --base c34d3b7~2 --head HEAD
    python -m experiments.rebuild_ab --base HEAD~1 --head HEAD --pairs 1 --ticks 2   # quick
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):   # run as a script: make ``experiments`` importable
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from experiments._results import write_results  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def child(n: int, ticks: int, repeats: int) -> dict:
    """One process's measurement, run inside a worktree (its ``jaxplan`` and ``experiments``)."""
    import jax

    from experiments.bench_fabric import make_scene
    from experiments.table2 import _best_route
    from jaxplan import FabricParams, SpillParams, build_fabric, execute, rebuild

    params, spill = FabricParams(), SpillParams(lam=0.05)
    best_route = jax.jit(_best_route, static_argnums=2)

    selective, full = [], []
    for density in (0.2, 0.4, 0.6):
        scene = make_scene(n, density, 0)
        scene = scene.with_obj(execute.quantize(scene.obj))
        fabric = build_fabric(scene, params)
        for _ in range(ticks):
            route, _ = best_route(scene, fabric, 8 * n)
            new_obj, push = execute.execute_jit(scene, route, spill)
            scene = scene.with_obj(new_obj)
            sel_t, full_t = [], []
            for _ in range(repeats):
                start = time.perf_counter()
                rebuilt, _ = jax.block_until_ready(rebuild.selective_rebuild(scene, params, fabric, push.changed))
                sel_t.append(time.perf_counter() - start)
                start = time.perf_counter()
                jax.block_until_ready(build_fabric(scene, params))
                full_t.append(time.perf_counter() - start)
            selective.append(1e3 * statistics.median(sel_t))
            full.append(1e3 * statistics.median(full_t))
            fabric = rebuilt
    return {"selective_ms": statistics.median(selective), "full_ms": statistics.median(full), "pushes": len(selective)}


def _run_child(worktree: Path, args) -> dict:
    env = dict(os.environ, PYTHONPATH=str(worktree))
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", str(args.n), str(args.ticks),
                          str(args.repeats)], cwd=worktree, env=env, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _revision(rev: str) -> str:
    return subprocess.run(["git", "rev-parse", "--short", rev], cwd=REPO, check=True, capture_output=True,
                          text=True).stdout.strip()


def markdown(result) -> str:
    lines = ["# Selective update and full build: two commits in alternating processes", "",
             f"{result['date']}, {result['n']}^2, densities 0.2 / 0.4 / 0.6, {result['ticks']} pushes each, "
             f"{result['repeats']} calls per push (median); each cell the median over one process's pushes.", "",
             f"| pair | selective ms, {result['base']} | selective ms, {result['head']} | full ms, {result['base']} "
             f"| full ms, {result['head']} |", "|---|---|---|---|---|"]
    for i, (b, h) in enumerate(zip(result["runs"]["base"], result["runs"]["head"]), 1):
        lines.append(f"| {i} | {b['selective_ms']:.2f} | {h['selective_ms']:.2f} | {b['full_ms']:.2f} | {h['full_ms']:.2f} |")
    lines += ["", f"Head / base, median over pairs: selective {result['selective_ratio']:.3f}, "
                  f"full {result['full_ratio']:.3f}."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    if argv is None and sys.argv[1:2] == ["--child"]:
        print(json.dumps(child(*(int(a) for a in sys.argv[2:5]))))
        return 0
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--base", required=True, help="git revision to compare against")
    p.add_argument("--head", default="HEAD", help="git revision under test")
    p.add_argument("--pairs", type=int, default=3, help="alternating base/head process pairs")
    p.add_argument("--n", type=int, default=65, help="grid side")
    p.add_argument("--ticks", type=int, default=6, help="pushes per density")
    p.add_argument("--repeats", type=int, default=9, help="timed calls of each operation per push")
    p.add_argument("--results-dir", type=Path, default=REPO / "experiments" / "results")
    args = p.parse_args(argv)
    base, head = _revision(args.base), _revision(args.head)
    runs = {"base": [], "head": []}
    with tempfile.TemporaryDirectory() as tmp:
        trees = {}
        for name, rev in (("base", base), ("head", head)):
            trees[name] = Path(tmp) / name
            subprocess.run(["git", "worktree", "add", "--detach", str(trees[name]), rev], cwd=REPO, check=True,
                           capture_output=True)
        try:
            for i in range(args.pairs):
                for name in ("base", "head"):
                    runs[name].append(_run_child(trees[name], args))
                    print(f"pair {i + 1} {name} {runs[name][-1]}", file=sys.stderr, flush=True)
        finally:
            for tree in trees.values():
                subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=REPO, capture_output=True)
    ratio = lambda key: statistics.median(h[key] / b[key] for b, h in zip(runs["base"], runs["head"]))  # noqa: E731
    result = {"date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), "base": base, "head": head,
              "n": args.n, "ticks": args.ticks, "repeats": args.repeats, "runs": runs,
              "selective_ratio": ratio("selective_ms"), "full_ratio": ratio("full_ms")}
    write_results(args.results_dir, "rebuild_ab", result, markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
