"""Where a planning process's memory goes: resident memory after each first call, in one fresh process.

Table 2's memory probe (``experiments/table2.py --memory-only``) gives the peak of a whole planning
run; this splits it. A fresh process (start it on its own: the numbers are per process) builds the
benchmark's random n x n scene, the fabric, a selective update with nothing changed, then pushes
``--ticks`` routes (extract, route, execute, selective update, full build), and records RSS and the
high-water mark (VmHWM) after each step. Steps after the first tick are only listed when they raised
the high-water mark (new buffer sizes compiling). Writes ``experiments/results/memory_steps.{json,md}``.

    python experiments/memory_steps.py            # 65 x 65
    python experiments/memory_steps.py --size 45
"""
from __future__ import annotations

import argparse
import datetime as _dt
import platform
import re
from pathlib import Path

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def _mb(field: str) -> float:
    return int(re.search(rf"{field}:\s+(\d+)", Path("/proc/self/status").read_text()).group(1)) / 1024


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=65, help="grid side (default 65)")
    ap.add_argument("--ticks", type=int, default=8, help="pushes (default 8)")
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = ap.parse_args(argv)
    steps = []

    def record(label):
        steps.append({"step": label, "rss_mb": round(_mb("VmRSS"), 1), "peak_mb": round(_mb("VmHWM"), 1)})

    record("python started")
    import jax
    import jax.numpy as jnp

    from experiments._results import write_results
    from experiments.bench_fabric import make_scene
    from jaxplan import FabricParams, SpillParams, build_fabric, execute, extract_paths, rebuild

    jnp.zeros(1).block_until_ready()
    record("jax up, jaxplan imported")
    n, params, spill = args.size, FabricParams(), SpillParams(lam=0.05)
    scene = make_scene(n, 0.4, 0)
    scene = scene.with_obj(execute.quantize(scene.obj))
    record("scene (the process's first XLA compilation)")
    fabric = jax.block_until_ready(build_fabric(scene, params))
    record("build_fabric")
    jax.block_until_ready(rebuild.selective_rebuild(scene, params, fabric, jnp.zeros(scene.shape, bool)))
    record("selective update, nothing changed (the listing only: nothing is dirty)")
    for t in range(args.ticks):
        source = jnp.unravel_index(jnp.argmax(jnp.where(fabric.occupied, fabric.value, -jnp.inf)), scene.shape)
        paths = extract_paths(fabric, jnp.stack(source)[None], max_steps=8 * n)
        if t == 0:
            record("extract_paths")
        route = jax.tree.map(lambda a: a[0], execute.routes_from_paths(scene, paths))
        if t == 0:
            record("routes_from_paths")
        new_obj, push = execute.execute_jit(scene, route, spill)
        jax.block_until_ready(new_obj)
        if t == 0:
            record("execute_jit")
        scene = scene.with_obj(new_obj)
        before = steps[-1]["peak_mb"]
        fabric, affected = rebuild.selective_rebuild(scene, params, fabric, push.changed)
        jax.block_until_ready(fabric)
        jax.block_until_ready(build_fabric(scene, params))
        label = f"tick {t}: selective update ({int(affected.n_dirty)} dirty cells) and full build"
        if t == 0 or _mb("VmHWM") > before + 1.0:
            record(label)
    record("end")
    result = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "host": platform.platform(),
              "jax": jax.__version__, "size": n, "ticks": args.ticks, "steps": steps}
    lines = [f"# Memory of one planning process, step by step ({n}x{n})", "",
             f"{result['date']}, {result['host']}, jax {result['jax']}. Density 0.4, seed 0, {args.ticks} pushes; "
             "RSS and peak (VmHWM) after each step; delta = RSS change from the step before.", "",
             "| step | RSS MB | delta MB | peak MB |", "|---|---:|---:|---:|"]
    prev = None
    for s in steps:
        delta = "" if prev is None else f"{s['rss_mb'] - prev:+.0f}"
        lines.append(f"| {s['step']} | {s['rss_mb']:.0f} | {delta} | {s['peak_mb']:.0f} |")
        prev = s["rss_mb"]
    write_results(args.results_dir, "memory_steps", result, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
