"""Where the selective update's solver program spends its time, kernel by kernel.

After one push on a Table 2 scene (``bench_fabric.make_scene``, ``--density``, seed 0), the
rebuild's finish program (``rebuild._finish_jit``: compact solver, own fields, psi, heatmap,
highways) runs ``--calls`` times under JAX's profiler, with XLA tracing each kernel. Every kernel
is attributed, through the compiled program's stack-frame table, to the innermost Python function
that emitted it; the table lists kernel self time and kernel launches per call by function.
Profiling inflates the times (about 2x), so the shares are the figures to read. Writes
``experiments/results/profile_rebuild.{json,md}``.

    python -m experiments.profile_rebuild                    # 65^2, density 0.4
    taskset -c 0 python -m experiments.profile_rebuild       # one core: no thread hand-offs
"""
from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import os
import re
import sys
import tempfile
from pathlib import Path

if __package__ in (None, ""):   # run as a script: make ``experiments`` importable
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from experiments._results import write_results  # noqa: E402
from experiments.bench_fabric import RESULTS_DIR, make_scene, stamp  # noqa: E402

_TRACE_FLAG = "--xla_cpu_enable_xprof_traceme=true"


def enable_kernel_trace() -> None:
    """Ask XLA to trace every kernel for the profiler. Call it before the process's first JAX
    computation (XLA reads its flags once, when the backend starts), as ``main`` does; not at
    import, so that importing this module (a test does) changes no flag."""
    if _TRACE_FLAG not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _TRACE_FLAG).strip()


def _section(hlo: str, title: str) -> list[str]:
    start = hlo.index("\n" + title + "\n") + len(title) + 2
    return [line for line in hlo[start:hlo.find("\n\n", start)].split("\n") if line.strip()]


def kernel_functions(hlo: str) -> dict:
    """``{kernel name: innermost Python function}`` from a compiled program's text."""
    names = {int(line.split(" ", 1)[0]): line.split(" ", 1)[1].strip('"') for line in _section(hlo, "FunctionNames")}
    location = {int(line.split(" ", 1)[0]): names[int(re.search(r"function_name_id=(\d+)", line).group(1))]
                for line in _section(hlo, "FileLocations")}
    frame = {int(line.split(" ", 1)[0]): location[int(re.search(r"file_location_id=(\d+)", line).group(1))]
             for line in _section(hlo, "StackFrames")}
    return {m.group(1): frame.get(int(m.group(2)), "?")
            for m in re.finditer(r"%([\w.\-]+) = .*?stack_frame_id=(\d+)", hlo)}


def self_times(trace_dir: str) -> dict:
    """``{event name: (count, self time us)}`` over all threads of a perfetto trace."""
    path = glob.glob(os.path.join(trace_dir, "**", "*.trace.json.gz"), recursive=True)[0]
    events = [e for e in json.load(gzip.open(path))["traceEvents"] if e.get("ph") == "X"]
    by_thread = collections.defaultdict(list)
    for e in events:
        by_thread[(e["pid"], e["tid"])].append(e)
    totals = collections.defaultdict(lambda: [0, 0.0])
    for thread in by_thread.values():
        thread.sort(key=lambda e: (e["ts"], -e["dur"]))
        stack, children = [], collections.defaultdict(float)
        for e in thread:
            while stack and stack[-1]["ts"] + stack[-1]["dur"] <= e["ts"]:
                stack.pop()
            if stack:
                children[id(stack[-1])] += e["dur"]
            stack.append(e)
        for e in thread:
            totals[e["name"]][0] += 1
            totals[e["name"]][1] += e["dur"] - children[id(e)]
    return totals


def profile(n: int, density: float, calls: int) -> dict:
    import jax

    from experiments.table2 import _best_route
    from jaxplan import FabricParams, SpillParams, build_fabric, execute, rebuild

    params = FabricParams()
    scene = make_scene(n, density, 0)
    scene = scene.with_obj(execute.quantize(scene.obj))
    fabric = build_fabric(scene, params)
    route, _ = jax.jit(_best_route, static_argnums=2)(scene, fabric, 8 * n)
    new_obj, push = execute.execute_jit(scene, route, SpillParams(lam=0.05))
    scene = scene.with_obj(new_obj)
    capacity = rebuild.default_capacity(scene.shape)
    dense, local = rebuild.dense_listing_default(scene.shape), rebuild.local_flow_default(scene.shape)
    cells, count, dirty, _ = rebuild._listing_jit(scene, params, fabric, push.changed, capacity, dense)
    fitting = [c for c in rebuild.capacity_buckets(capacity) if c >= int(count)]
    if not fitting:
        raise SystemExit("profile_rebuild: the push dirtied more cells than any buffer holds (a full build)")
    args = (scene, params, fabric, push.changed, cells, count, dirty, fitting[0], local, False)
    program = rebuild._finish_jit._pick(args, {})
    functions = kernel_functions(program.lower(*args).compile().as_text())
    for _ in range(10):
        jax.block_until_ready(rebuild._finish_jit(*args))
    with tempfile.TemporaryDirectory() as trace_dir:
        options = jax.profiler.ProfileOptions()
        options.python_tracer_level = 0
        with jax.profiler.trace(trace_dir, create_perfetto_trace=True, profiler_options=options):
            for _ in range(calls):
                jax.block_until_ready(rebuild._finish_jit(*args))
        totals = self_times(trace_dir)
    by_function = collections.defaultdict(lambda: [0, 0.0])
    for name, (count_, us) in totals.items():
        if name in functions:
            by_function[functions[name]][0] += count_
            by_function[functions[name]][1] += us
    kernel_us = sum(us for _, us in by_function.values())
    rows = [{"function": f, "kernels_per_call": c / calls, "us_per_call": us / calls, "share": us / kernel_us}
            for f, (c, us) in sorted(by_function.items(), key=lambda kv: -kv[1][1])]
    return {"n": n, "density": density, "dirty": int(count), "buffer": fitting[0], "calls": calls,
            "kernels_per_call": sum(r["kernels_per_call"] for r in rows), "kernel_us_per_call": kernel_us / calls,
            "rows": rows}


def markdown(result, top: int = 25) -> str:
    env = result["environment"]
    lines = ["# The selective update's solver program, by function", "",
             f"{env['cpu_model']}, {env['cpus_available']} cores available, jax {env['jax_version']}; {result['date']}. "
             f"{result['n']}^2, density {result['density']}, {result['dirty']} dirty cells in a buffer of "
             f"{result['buffer']}; {result['calls']} profiled calls. {result['kernels_per_call']:.0f} kernels and "
             f"{result['kernel_us_per_call']:.0f} us of kernel self time per call (inflated by the profiler).", "",
             "| function (innermost) | kernels per call | us per call | share |", "|---|---|---|---|"]
    for row in result["rows"][:top]:
        lines.append(f"| `{row['function']}` | {row['kernels_per_call']:.1f} | {row['us_per_call']:.1f} | "
                     f"{100 * row['share']:.1f}% |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=65, help="grid side")
    p.add_argument("--density", type=float, default=0.4)
    p.add_argument("--calls", type=int, default=20, help="profiled calls of the finish program")
    p.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = p.parse_args(argv)
    enable_kernel_trace()
    result = {**profile(args.n, args.density, args.calls), **stamp()}
    write_results(args.results_dir, "profile_rebuild", result, markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
