"""Where a 65^2 selective update spends its time outside the kernels: program launches and hand-offs.

Three measurements, in one process, on a Table 2 scene (``bench_fabric.make_scene``, density 0.4):

1. **One program against two.** ``selective_rebuild`` runs two programs (the dirty-cell listing,
   then the solver for the buffer size the host picks from the dirty count). The peer
   ``one_program`` below does both in one program, with every buffer size compiled behind a
   ``lax.switch`` and no read on the host (a design that was tried for the library and not kept).
   A third variant runs the peer and then reads its dirty count on the host, as a library path on
   it must (to fall back when the dirty set overflows). After each of ``--ticks`` pushes (seeds 0
   and 1), the three run ``--repeats`` times, alternating in a rotating order, each call right
   after a full build as in Table 2, once their fabrics are checked equal. Reported: medians over
   the pushes of each push's median, each variant's paired ratio to the library's, and the peer's
   compile time.
2. **Launch timeline of the solver program** (``rebuild._finish_jit``), from XLA's per-kernel trace
   over ``--calls`` profiled calls, 2 ms apart (so XLA's threads sleep when each call starts): the
   time from the Python call to its first kernel (the launch: argument handling, buffer set-up, the
   wake-up of XLA's thread), the span of its kernels, their number, their summed duration, and the
   share of it on each XLA thread. The profiler inflates kernel times (about 2x); the launch is
   measured before the first kernel, where it adds little.
3. **Thread sleeps per call**: the process's voluntary context switches (``getrusage``, all
   threads) per selective update and per full build, over 10 x ``--calls`` calls each. Each is a
   thread that ran out of work and had to be woken again.

Run it as it is (two cores) and under ``taskset -c 0`` (one core; then give ``--results-dir
experiments/results/single_cpu``) to compare the two. Writes ``update_overheads.{json,md}``.

    python -m experiments.update_overheads
    taskset -c 0 python -m experiments.update_overheads --results-dir experiments/results/single_cpu
"""
from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):   # run as a script: make ``experiments`` importable
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from experiments._results import write_results  # noqa: E402
from experiments.bench_fabric import RESULTS_DIR, stamp  # noqa: E402
from experiments.listing_ab import _pushes  # noqa: E402
from experiments.profile_rebuild import enable_kernel_trace, kernel_functions  # noqa: E402


def one_program(scene, params, fabric, changed, capacity: int, local: bool, dense: bool):
    """The peer: listing, solver and refresh in one program for a fabric that follows entry 0 and a
    dirty set within ``capacity`` (the cases Table 2 meets; the library's own path covers the rest).
    A ``lax.switch`` picks the smallest buffer that holds the dirty cells, or keeps ``fabric`` when
    none is dirty."""
    import jax
    import jax.numpy as jnp

    from jaxplan import rebuild

    cells, count, dirty, _ = rebuild._listing(scene, params, fabric, changed, capacity, dense)
    buckets = rebuild.capacity_buckets(capacity)

    def kept(_):
        return fabric._replace(rounds=jnp.zeros_like(fabric.rounds))

    def solve_in(size):
        def solve(_):
            own, hop_len = rebuild._partial(scene, params, fabric, cells[:size], False)
            return rebuild._flow(scene, params, fabric, own, hop_len, cells[:size], dirty, local, False)
        return solve

    branch = jnp.where(count > 0, 1 + jnp.argmax(jnp.asarray(buckets) >= count), 0)
    return jax.lax.switch(branch, [kept] + [solve_in(size) for size in buckets], None), count


def _pushed(n: int, seed: int, ticks: int):
    """``(scene after the push, fabric before it, changed)`` after each of ``ticks`` Table 2 pushes
    on a density-0.4 scene (``listing_ab._pushes``)."""
    from jaxplan import FabricParams, SpillParams

    return _pushes(n, seed, ticks, FabricParams(), SpillParams(lam=0.05))


def _same(a, b) -> bool:
    import jax
    import numpy as np

    return all(np.array_equal(np.asarray(x), np.asarray(y))
               for x, y in zip(jax.tree.leaves(a._replace(rounds=0)), jax.tree.leaves(b._replace(rounds=0))))


def programs_ab(n: int, ticks: int, repeats: int) -> dict:
    import jax
    import numpy as np

    from jaxplan import FabricParams, _compile, build_fabric, rebuild

    params = FabricParams()
    capacity = rebuild.default_capacity((n, n))
    local, dense = rebuild.local_flow_default((n, n)), rebuild.dense_listing_default((n, n))
    # compiled as the library compiles its programs on grids of this size (``_compile.grid_jit``)
    peer = jax.jit(one_program, static_argnums=(4, 5, 6), compiler_options=_compile._SMALL_GRID_OPTIONS)

    def peer_with_read(s, f, c):
        # what a library path on the peer must do: read the dirty count (to fall back when the set
        # overflows), which waits for the program on the host
        fabric, count = peer(s, params, f, c, capacity, local, dense)
        int(np.asarray(count))
        return fabric

    variants = {"two programs (library)": lambda s, f, c: rebuild.selective_rebuild(s, params, f, c),
                "one program (peer)": lambda s, f, c: peer(s, params, f, c, capacity, local, dense)[0],
                "one program, count read on the host": peer_with_read}
    medians = {name: [] for name in variants}
    compile_s = None
    for seed in (0, 1):
        for scene, fabric, changed in _pushed(n, seed, ticks):
            if compile_s is None:
                start = time.perf_counter()
                jax.block_until_ready(variants["one program (peer)"](scene, fabric, changed))
                compile_s = time.perf_counter() - start
            outputs = [jax.block_until_ready(run(scene, fabric, changed)) for run in variants.values()]
            if not all(_same(outputs[0][0], other) for other in outputs[1:]):
                raise SystemExit("update_overheads: the one-program peer differs from selective_rebuild")
            times = {name: [] for name in variants}
            order = list(variants.items())
            for r in range(repeats):
                # alternate, so drifts hit all alike, and rotate the order: a call runs measurably
                # slower or faster depending on which variant ran before it
                for name, run in order[r % len(order):] + order[:r % len(order)]:
                    jax.block_until_ready(build_fabric(scene, params))
                    start = time.perf_counter()
                    jax.block_until_ready(run(scene, fabric, changed))
                    times[name].append((time.perf_counter() - start) * 1e3)
            for name in variants:
                medians[name].append(statistics.median(times[name]))
    two = medians["two programs (library)"]
    return {"pushes": len(two), "repeats": repeats, "peer_first_call_s": compile_s,
            "median_ms": {name: statistics.median(v) for name, v in medians.items()},
            "ratio_to_two": {name: statistics.median(o / t for o, t in zip(v, two))
                             for name, v in medians.items() if v is not two},
            "per_push_ms": medians}


def _trace_events(trace_dir: str):
    path = glob.glob(os.path.join(trace_dir, "**", "*.trace.json.gz"), recursive=True)[0]
    trace = json.load(gzip.open(path))
    names = {(e["pid"], e["tid"]): e["args"]["name"] for e in trace["traceEvents"]
             if e.get("ph") == "M" and e.get("name") == "thread_name"}
    return [e for e in trace["traceEvents"] if e.get("ph") == "X"], names


def launch_timeline(n: int, calls: int) -> dict:
    import jax

    from jaxplan import FabricParams, rebuild

    params = FabricParams()
    scene, fabric, changed = next(_pushed(n, 0, 1))
    capacity = rebuild.default_capacity((n, n))
    cells, count, dirty, _ = rebuild._listing_jit(scene, params, fabric, changed, capacity,
                                                  rebuild.dense_listing_default((n, n)))
    bucket = [c for c in rebuild.capacity_buckets(capacity) if c >= int(count)][0]
    args = (scene, params, fabric, changed, cells, count, dirty, bucket, rebuild.local_flow_default((n, n)), False)
    program = rebuild._finish_jit._pick(args, {})
    kernels = kernel_functions(program.lower(*args).compile().as_text())
    for _ in range(10):
        jax.block_until_ready(program(*args))
    with tempfile.TemporaryDirectory() as trace_dir:
        options = jax.profiler.ProfileOptions()
        options.python_tracer_level = 0
        with jax.profiler.trace(trace_dir, create_perfetto_trace=True, profiler_options=options):
            for _ in range(calls):
                jax.block_until_ready(program(*args))
                time.sleep(0.002)   # keeps the calls apart in the trace
        events, thread_names = _trace_events(trace_dir)
    starts = sorted((e["ts"] for e in events if e["name"].startswith("PjitFunction(")))
    starts = [t for i, t in enumerate(starts) if i == 0 or t - starts[i - 1] > 1000.0]   # outermost per call
    launch, span, count_k, busy = [], [], [], []
    by_thread = collections.Counter()
    for i, start in enumerate(starts):
        end = starts[i + 1] if i + 1 < len(starts) else float("inf")
        mine = [e for e in events if e["name"] in kernels and start <= e["ts"] < end]
        if not mine:
            continue
        first = min(e["ts"] for e in mine)
        last = max(e["ts"] + e["dur"] for e in mine)
        launch.append(first - start)
        span.append(last - first)
        count_k.append(len(mine))
        busy.append(sum(e["dur"] for e in mine))
        for e in mine:
            by_thread[thread_names.get((e["pid"], e["tid"]), str(e["tid"])).split("/")[0]] += e["dur"]
    if not launch:
        raise SystemExit("update_overheads: the trace holds no kernel of the solver program; XLA's kernel "
                         "tracing must be on before JAX starts (enable_kernel_trace, as main does)")
    total = sum(by_thread.values()) or 1.0
    return {"bucket": bucket, "dirty": int(count), "calls": len(launch),
            "launch_us": statistics.median(launch), "kernel_span_us": statistics.median(span),
            "kernels_per_call": statistics.median(count_k), "kernel_time_us": statistics.median(busy),
            "kernel_time_share_by_thread": {k: v / total for k, v in by_thread.most_common()}}


def context_switches(n: int, calls: int) -> dict:
    import resource

    import jax

    from jaxplan import FabricParams, build_fabric, rebuild

    params = FabricParams()
    scene, fabric, changed = next(_pushed(n, 0, 1))
    runs = {"selective update": lambda: rebuild.selective_rebuild(scene, params, fabric, changed),
            "full build": lambda: build_fabric(scene, params)}
    out = {}
    for name, run in runs.items():
        jax.block_until_ready(run())
        before = resource.getrusage(resource.RUSAGE_SELF).ru_nvcsw
        for _ in range(calls):
            jax.block_until_ready(run())
        out[name] = (resource.getrusage(resource.RUSAGE_SELF).ru_nvcsw - before) / calls
    return out


def markdown(result) -> str:
    env, ab, tl = result["environment"], result["programs"], result["launch"]
    names = list(ab["median_ms"])
    lines = ["# A 65^2 selective update outside its kernels", "",
             f"{env['cpu_model']}, {env['cpus_available']} cores available, jax {env['jax_version']}; {result['date']}. "
             f"Density 0.4, seeds 0 and 1.", "",
             f"## One program against two ({ab['pushes']} pushes, {ab['repeats']} alternating calls each, "
             "each right after a full build)", "",
             "| variant | median ms | paired ratio to two programs |", "|---|---|---|"]
    lines += [f"| {name} | {ab['median_ms'][name]:.3f} | "
              + (f"{ab['ratio_to_two'][name]:.3f} |" if name in ab["ratio_to_two"] else "1 |") for name in names]
    lines += ["", f"First call of the one-program peer (compiling every buffer size): {ab['peer_first_call_s']:.1f} s.", "",
              f"## The solver program's launch ({tl['calls']} profiled calls, buffer {tl['bucket']}, "
              f"{tl['dirty']} dirty cells)", "",
              "| Python call to first kernel, us | kernel span, us | kernels | summed kernel time, us |",
              "|---|---|---|---|",
              f"| {tl['launch_us']:.0f} | {tl['kernel_span_us']:.0f} | {tl['kernels_per_call']:.0f} | "
              f"{tl['kernel_time_us']:.0f} |", "",
              "Kernel time by XLA thread: " + ", ".join(f"{k} {100 * v:.0f}%"
                                                        for k, v in tl["kernel_time_share_by_thread"].items())
              + ". Kernel times are inflated by the profiler (about 2x).", "",
              "## Thread sleeps (voluntary context switches of the process) per call", "",
              "| call | context switches |", "|---|---|"]
    lines += [f"| {name} | {v:.1f} |" for name, v in result["context_switches"].items()]
    lines += [""]
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=65, help="grid side (at most 80: larger grids have too many buffer sizes)")
    p.add_argument("--ticks", type=int, default=4, help="pushes per seed")
    p.add_argument("--repeats", type=int, default=15, help="alternating timed calls per push and variant")
    p.add_argument("--calls", type=int, default=10, help="profiled calls of the solver program")
    p.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = p.parse_args(argv)
    if not 4 <= args.n <= 80:
        p.error(f"--n must be between 4 and 80, got {args.n}")
    enable_kernel_trace()
    result = {"n": args.n, "programs": programs_ab(args.n, args.ticks, args.repeats),
              "launch": launch_timeline(args.n, args.calls),
              "context_switches": context_switches(args.n, 10 * args.calls), **stamp()}
    write_results(args.results_dir, "update_overheads", result, markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
