"""Benchmark of the full fabric (``build_fabric``: visibility, DP, psi, heatmap, highways).

Part 1 (paper grids, Table 2 protocol): 25x25, 45x45, 65x65 at densities 0.2 / 0.4 / 0.6 and
``--seeds`` seeds. Per instance: JAX ``build_fabric`` (one warm-up call compiles, then the median of
``--repeats`` calls, each ended by ``jax.block_until_ready``) and, in the same run, the serial
reference ``jaxplan.reference.reference_fabric(..., with_connectors=False)`` (median of
``--ref-repeats`` calls). Per grid size: medians across instances with 95% bootstrap CIs (2000
resamples of the instances), and the ratio reference / JAX (median of the per-instance ratios).

Part 2 (scaling): JAX alone on ``--big-sizes`` (default 128^2 .. 1024^2): time, peak memory (RSS
sampled from /proc/self/statm, see the output for the method used) and the log-log slope of time
vs cells (numpy polyfit, with R^2).

Scenes: uniform random integer counts 1..6 on a fraction ``density`` of the non-target cells, a
circular target (64-gon) of radius max(2.5, 0.1 n) cells at the grid centre, cell size 1.

Results: a markdown table on stdout, ``experiments/results/<name>.json`` and ``<name>.md``
(name = ``fabric``, or ``fabric_quick`` with ``--quick``). The issue's targets are checked at the
end (met / not met; never asserted).

Examples::

    python -m experiments.bench_fabric --quick          # smoke run, ~1 minute
    python -m experiments.bench_fabric                  # full run (long: 1024^2 included)
    python -m experiments.bench_fabric --single-cpu     # pin to one core, like the paper's setup
    python -m experiments.bench_fabric --targets        # re-print the targets of the saved results
"""
from __future__ import annotations

import argparse
import datetime as _dt
import gc
import json
import os
import platform
import resource
import sys
import threading
import time
from pathlib import Path

import numpy as np

RESULTS_DIR = Path(__file__).resolve().parent / "results"
PAPER_FULL_CALC_MS = {25: 420.0, 45: 980.0, 65: 1910.0}  # Table 2, full calc, medians
PAPER_FULL_CALC_CI = {25: (380.0, 465.0), 45: (910.0, 1060.0), 65: (1780.0, 2050.0)}
TARGETS = {"ms_65": 2.0, "speedup_65": 300.0, "ms_1024": 1000.0, "slope": 1.1}
N_BOOT = 2000


# --------------------------------------------------------------------------------------------------
# Statistics
# --------------------------------------------------------------------------------------------------

def bootstrap_ci(values, n_boot: int = N_BOOT, seed: int = 0):
    """Median and 95% percentile-bootstrap CI of the median: ``(median, lo, hi)``."""
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    med = float(np.median(x))
    if x.size == 1:
        return med, med, med
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, x.size, size=(n_boot, x.size))
    meds = np.median(x[idx], axis=1)
    lo, hi = np.percentile(meds, [2.5, 97.5])
    return med, float(lo), float(hi)


def loglog_fit(cells, times):
    """Slope, intercept and R^2 of ``log(time) = a log(cells) + b`` (None with < 2 points)."""
    x = np.log(np.asarray(cells, dtype=np.float64))
    y = np.log(np.asarray(times, dtype=np.float64))
    if x.size < 2:
        return None
    slope, intercept = np.polyfit(x, y, 1)
    pred = slope * x + intercept
    ss_res = float(np.sum((y - pred) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0
    return {"slope": float(slope), "intercept": float(intercept), "r2": float(r2),
            "points": int(x.size)}


# --------------------------------------------------------------------------------------------------
# Memory
# --------------------------------------------------------------------------------------------------

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_bytes():
    """Current resident set size from /proc/self/statm, or None where /proc is unavailable."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return None


def _maxrss_bytes() -> int:
    # ru_maxrss is in KiB on Linux, bytes on macOS
    scale = 1 if sys.platform == "darwin" else 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale


class PeakMemory:
    """Peak host RSS while the block runs: sampled from /proc every ``interval`` s in a thread, or
    (without /proc) the ``ru_maxrss`` high-water-mark delta, which reads 0 when an earlier phase of
    the process had a higher peak."""

    def __init__(self, interval: float = 0.001):
        self.interval = interval
        self.method = ("RSS sampled from /proc/self/statm every 1 ms" if rss_bytes() is not None
                       else "resource.getrusage ru_maxrss delta (high-water mark)")
        self.baseline = self.peak = 0
        self._stop = threading.Event()
        self._thread = None

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, rss_bytes() or 0)
            time.sleep(self.interval)

    def __enter__(self):
        if rss_bytes() is not None:
            self.baseline = self.peak = rss_bytes()
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()
        else:
            self.baseline = self.peak = _maxrss_bytes()
        return self

    def __exit__(self, *exc):
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self.peak = max(self.peak, rss_bytes() or 0)
        else:
            self.peak = _maxrss_bytes()
        return False

    @property
    def delta_mb(self) -> float:
        return (self.peak - self.baseline) / 2 ** 20

    @property
    def peak_mb(self) -> float:
        return self.peak / 2 ** 20


def _device_peak_mb(device):
    try:
        stats = device.memory_stats()
    except Exception:  # not supported on every backend (e.g. CPU)
        return None
    if not stats or "peak_bytes_in_use" not in stats:
        return None
    return stats["peak_bytes_in_use"] / 2 ** 20


# --------------------------------------------------------------------------------------------------
# Scenes and timing
# --------------------------------------------------------------------------------------------------

def make_scene(n: int, density: float, seed: int):
    """Random n x n scene of the Table 2 protocol (``jaxplan.random_scene``, layout "uniform")."""
    from jaxplan import random_scene

    return random_scene(seed, (n, n), density)


def time_jax(scene, params, repeats: int):
    """Warm-up (compiles on the first shape), then ``repeats`` timed calls: (fabric, times_ms)."""
    import jax

    from jaxplan import build_fabric

    fabric = jax.block_until_ready(build_fabric(scene, params))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fabric = jax.block_until_ready(build_fabric(scene, params))
        times.append((time.perf_counter() - start) * 1e3)
    return fabric, times


def time_reference(scene, theta_tol: float, repeats: int):
    from jaxplan.reference import reference_fabric

    args = (np.asarray(scene.obj), np.asarray(scene.target_mask), np.asarray(scene.dist),
            np.asarray(scene.tvec), float(np.asarray(scene.cell_size)), theta_tol)
    times, ref = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        ref = reference_fabric(*args, with_connectors=False)
        times.append((time.perf_counter() - start) * 1e3)
    return ref, times


# --------------------------------------------------------------------------------------------------
# Runs
# --------------------------------------------------------------------------------------------------

def run_paper_grids(args, params, log):
    instances = []
    total = len(args.sizes) * len(args.densities) * args.seeds
    done = 0
    for n in args.sizes:
        for density in args.densities:
            for seed in range(args.seeds):
                scene = make_scene(n, density, seed)
                fabric, jax_times = time_jax(scene, params, args.repeats)
                row = {"n": n, "density": density, "seed": seed,
                       "occupied": int(np.asarray(fabric.occupied).sum()),
                       "mass": float(np.asarray(scene.total_mass)),
                       "solver_iterations": int(fabric.rounds),
                       "jax_ms": float(np.median(jax_times)), "jax_ms_all": jax_times}
                if not args.no_reference:
                    ref, ref_times = time_reference(scene, args.theta_tol, args.ref_repeats)
                    row["ref_ms"] = float(np.median(ref_times))
                    row["ref_ms_all"] = ref_times
                    row["ratio"] = row["ref_ms"] / row["jax_ms"]
                    row["value_max_abs_diff"] = float(np.max(np.abs(
                        np.asarray(ref.value, np.float64) - np.asarray(fabric.value, np.float64))))
                    row["highways_equal"] = bool(np.array_equal(np.asarray(ref.highways),
                                                                np.asarray(fabric.highways)))
                instances.append(row)
                done += 1
                ref_txt = (f", reference {row['ref_ms']:.1f} ms ({row['ratio']:.1f}x)"
                           if "ref_ms" in row else "")
                log(f"[{done}/{total}] {n}x{n} density {density:g} seed {seed}: "
                    f"JAX {row['jax_ms']:.2f} ms{ref_txt}")
    summary = []
    for n in args.sizes:
        rows = [r for r in instances if r["n"] == n]
        entry = {"n": n, "instances": len(rows),
                 "occupied_median": float(np.median([r["occupied"] for r in rows])),
                 "jax_ms": bootstrap_ci([r["jax_ms"] for r in rows])}
        if not args.no_reference:
            entry["ref_ms"] = bootstrap_ci([r["ref_ms"] for r in rows])
            entry["ratio"] = bootstrap_ci([r["ratio"] for r in rows])
            entry["ratio_of_medians"] = entry["ref_ms"][0] / entry["jax_ms"][0]
            entry["all_values_match"] = all(r["value_max_abs_diff"] == 0.0 for r in rows)
            entry["all_highways_match"] = all(r["highways_equal"] for r in rows)
        entry["paper_full_calc_ms"] = PAPER_FULL_CALC_MS.get(n)
        summary.append(entry)
    by_density = []
    for n in args.sizes:
        for density in args.densities:
            rows = [r for r in instances if r["n"] == n and r["density"] == density]
            entry = {"n": n, "density": density,
                     "occupied_median": float(np.median([r["occupied"] for r in rows])),
                     "solver_iterations_median": float(np.median([r["solver_iterations"] for r in rows])),
                     "jax_ms": float(np.median([r["jax_ms"] for r in rows]))}
            if not args.no_reference:
                entry["ref_ms"] = float(np.median([r["ref_ms"] for r in rows]))
                entry["ratio"] = float(np.median([r["ratio"] for r in rows]))
            by_density.append(entry)
    return instances, summary, by_density


def run_big(args, params, log):
    import jax

    device = jax.devices()[0]
    rows = []
    method = PeakMemory().method
    for n in args.big_sizes:
        gc.collect()
        t0 = time.perf_counter()
        scene = make_scene(n, args.big_density, 0)
        jax.block_until_ready(scene.obj)
        scene_s = time.perf_counter() - t0
        with PeakMemory() as mem:
            t0 = time.perf_counter()
            fabric, times = time_jax(scene, params, args.big_repeats)
            total_s = time.perf_counter() - t0
        row = {"n": n, "cells": n * n, "density": args.big_density,
               "occupied": int(np.asarray(fabric.occupied).sum()),
               "solver_iterations": int(fabric.rounds), "converged": bool(fabric.converged),
               "jax_ms": float(np.median(times)), "jax_ms_min": float(np.min(times)),
               "jax_ms_all": times, "first_call_ms": (total_s * 1e3 - sum(times)),
               "scene_build_s": scene_s,
               "peak_rss_delta_mb": mem.delta_mb, "peak_rss_mb": mem.peak_mb,
               "device_peak_mb": _device_peak_mb(device)}
        rows.append(row)
        log(f"{n}x{n}: JAX {row['jax_ms']:.1f} ms (median of {len(times)}), "
            f"{row['solver_iterations']} solver iterations, peak RSS +{row['peak_rss_delta_mb']:.0f} MB")
        del fabric, scene
    fit = loglog_fit([r["cells"] for r in rows], [r["jax_ms"] for r in rows])
    return rows, fit, method


# --------------------------------------------------------------------------------------------------
# Targets and report
# --------------------------------------------------------------------------------------------------

def check_targets(result) -> list[tuple[str, str, str]]:
    """``(target, measured, verdict)`` for each of the issue's targets."""
    def verdict(ok):
        return "not measured" if ok is None else ("met" if ok else "not met")

    out = []
    s65 = next((s for s in result.get("paper_grids", {}).get("summary", []) if s["n"] == 65), None)
    ms65 = s65["jax_ms"][0] if s65 else None
    out.append(("65x65 full fabric <= 2 ms", "-" if ms65 is None else f"{ms65:.2f} ms",
                verdict(None if ms65 is None else ms65 <= TARGETS["ms_65"])))
    sp = s65["ratio"][0] if s65 and "ratio" in s65 else None
    out.append((">= 300x vs reference at 65x65", "-" if sp is None else f"{sp:.1f}x",
                verdict(None if sp is None else sp >= TARGETS["speedup_65"])))
    big = result.get("big", {}).get("rows", [])
    r1024 = next((r for r in big if r["n"] == 1024), None)
    ms1024 = r1024["jax_ms"] if r1024 else None
    out.append(("1024^2 <= 1 s", "-" if ms1024 is None else f"{ms1024:.0f} ms",
                verdict(None if ms1024 is None else ms1024 <= TARGETS["ms_1024"])))
    fit = result.get("big", {}).get("fit")
    slope = fit["slope"] if fit else None
    out.append(("log-log slope <= 1.1", "-" if slope is None else
                f"{slope:.2f} (R^2 {fit['r2']:.3f}, {fit['points']} sizes)",
                verdict(None if slope is None else slope <= TARGETS["slope"])))
    return out


def targets_line(result) -> str:
    return "targets: " + "; ".join(f"{t}: {m} -> {v.upper()}" for t, m, v in check_targets(result))


def _ci(triple, fmt="{:.2f}"):
    return [fmt.format(v) for v in triple]


def markdown(result) -> str:
    lines = []
    env = result["environment"]
    lines.append(f"# Fabric benchmark ({'quick' if result['config']['quick'] else 'full'} run)")
    lines.append("")
    lines.append(f"{env['timestamp']}; jax {env['jax_version']} on {env['backend']} "
                 f"({env['device']}); CPU: {env['cpu_model']}, {env['cpus_available']} core(s) "
                 f"available{'; pinned to one core' if result['config']['single_cpu'] else ''}; "
                 f"theta_tol {result['config']['theta_tol']:g} deg, K = 4, monotone rule on.")
    lines.append("")
    pg = result.get("paper_grids")
    if pg:
        cfg = result["config"]
        lines.append("## Full fabric on the paper's grids: JAX vs the serial reference")
        lines.append("")
        lines.append(f"Medians over {len(cfg['densities'])} densities "
                     f"({', '.join(f'{d:g}' for d in cfg['densities'])}) x {cfg['seeds']} seed(s); "
                     f"95% bootstrap CIs ({N_BOOT} resamples) in brackets. JAX: median of "
                     f"{cfg['repeats']} warm calls per instance (after a compiling warm-up), "
                     f"reference: median of {cfg['ref_repeats']} call(s). Ratio: median of the "
                     "per-instance ratios reference / JAX. Paper: Table 2 full-calc medians (their "
                     "implementation and machine, not re-measured).")
        lines.append("")
        has_ref = "ref_ms" in pg["summary"][0]
        head = "| Grid | instances | occupied (median) | JAX ms [95% CI] |"
        sep = "|---|---:|---:|---|"
        if has_ref:
            head += " reference ms [95% CI] | ratio ref/JAX [95% CI] | results equal |"
            sep += "---|---|---|"
        head += " paper Table 2 full calc (ms) |"
        sep += "---:|"
        lines += [head, sep]
        for s in pg["summary"]:
            j = _ci(s["jax_ms"])
            row = (f"| {s['n']}x{s['n']} | {s['instances']} | {s['occupied_median']:.0f} | "
                   f"{j[0]} [{j[1]}, {j[2]}] |")
            if has_ref:
                r = _ci(s["ref_ms"], "{:.1f}")
                q = _ci(s["ratio"], "{:.1f}")
                same = "yes" if s["all_values_match"] and s["all_highways_match"] else "NO"
                row += f" {r[0]} [{r[1]}, {r[2]}] | {q[0]}x [{q[1]}, {q[2]}] | {same} |"
            paper = s["paper_full_calc_ms"]
            row += f" {paper:,.0f} |" if paper is not None else " - |"
            lines.append(row)
        lines.append("")
        lines.append("Per density (medians over seeds):")
        lines.append("")
        head = "| Grid | density | occupied | solver iterations | JAX ms |"
        sep = "|---|---:|---:|---:|---:|"
        if has_ref:
            head += " reference ms | ratio |"
            sep += "---:|---:|"
        lines += [head, sep]
        for d in pg["by_density"]:
            row = (f"| {d['n']}x{d['n']} | {d['density']:g} | {d['occupied_median']:.0f} | "
                   f"{d['solver_iterations_median']:.0f} | {d['jax_ms']:.2f} |")
            if has_ref:
                row += f" {d['ref_ms']:.1f} | {d['ratio']:.1f}x |"
            lines.append(row)
        lines.append("")
    big = result.get("big")
    if big and big["rows"]:
        lines.append("## Scaling: JAX alone")
        lines.append("")
        lines.append(f"Density {result['config']['big_density']:g}, seed 0; median of "
                     f"{result['config']['big_repeats']} warm calls. Memory: {big['memory_method']}; "
                     "'delta' is the peak during the first (compiling) call and the timed calls "
                     "minus the RSS just before them.")
        lines.append("")
        lines.append("| Grid | cells | occupied | solver iterations | JAX ms (median) | min ms | "
                     "peak RSS delta MB | peak RSS MB | device peak MB |")
        lines.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
        for r in big["rows"]:
            dev = "-" if r["device_peak_mb"] is None else f"{r['device_peak_mb']:.0f}"
            lines.append(f"| {r['n']}x{r['n']} | {r['cells']:,} | {r['occupied']:,} | "
                         f"{r['solver_iterations']} | {r['jax_ms']:.1f} | {r['jax_ms_min']:.1f} | "
                         f"{r['peak_rss_delta_mb']:.0f} | {r['peak_rss_mb']:.0f} | {dev} |")
        lines.append("")
        fit = big["fit"]
        if fit:
            lines.append(f"log-log fit of time vs cells ({fit['points']} sizes): slope "
                         f"{fit['slope']:.3f}, R^2 {fit['r2']:.3f}"
                         + (" (2 points: R^2 is trivially 1)" if fit["points"] == 2 else "")
                         + ". Paper (their full calc, 25-65): slope ~1.03, R^2 0.988.")
            lines.append("")
    lines.append("## Targets")
    lines.append("")
    lines.append("| target | measured | verdict |")
    lines.append("|---|---|---|")
    for t, m, v in check_targets(result):
        lines.append(f"| {t} | {m} | {v} |")
    lines.append("")
    return "\n".join(lines)


def stamp() -> dict:
    """``{"environment", "date"}`` of a result measured in this process; pinned when the process may
    run on one CPU only (``taskset -c 0``, ``jaxplan.single_cpu``)."""
    pinned = hasattr(os, "sched_getaffinity") and len(os.sched_getaffinity(0)) == 1
    return {"environment": environment(pinned),
            "date": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")}


def environment(single_cpu: bool) -> dict:
    import jax

    cpu_model = platform.processor() or "unknown"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu_model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:
        cpus = os.cpu_count()
    dev = jax.devices()[0]
    return {
        "timestamp": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "python": platform.python_version(), "platform": platform.platform(),
        "jax_version": jax.__version__, "backend": jax.default_backend(),
        "device": getattr(dev, "device_kind", str(dev)), "cpu_model": cpu_model,
        "cpus_available": cpus, "single_cpu": single_cpu,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


# --------------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------------

def parse_args(argv=None):
    p = argparse.ArgumentParser(
        prog="python -m experiments.bench_fabric",
        description=__doc__.split("\n\n")[0] + " JAX vs the serial reference on 25/45/65 grids, "
                    "then JAX alone on large grids.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  python -m experiments.bench_fabric --quick\n"
               "  python -m experiments.bench_fabric --seeds 10 --big-sizes 128 256 512\n"
               "  python -m experiments.bench_fabric --targets")
    p.add_argument("--quick", action="store_true",
                   help="smoke run: 1 seed, grids 25/45/65 and big sizes 128/256; writes "
                        "<results>/fabric_quick.{json,md}")
    p.add_argument("--seeds", type=int, default=5, help="seeds per (grid, density); default 5")
    p.add_argument("--sizes", type=int, nargs="+", default=[25, 45, 65],
                   help="grid sides compared with the reference; default 25 45 65")
    p.add_argument("--densities", type=float, nargs="+", default=[0.2, 0.4, 0.6],
                   help="fractions of non-target cells holding objects; default 0.2 0.4 0.6")
    p.add_argument("--repeats", type=int, default=7, help="timed JAX calls per instance (>= 5)")
    p.add_argument("--ref-repeats", type=int, default=3,
                   help="timed reference calls per instance; default 3")
    p.add_argument("--no-reference", action="store_true", help="skip the serial reference")
    p.add_argument("--big-sizes", type=int, nargs="*", default=[128, 256, 512, 1024],
                   help="grid sides for the JAX-only scaling run; default 128 256 512 1024")
    p.add_argument("--big-density", type=float, default=0.4, help="density of the big grids")
    p.add_argument("--big-repeats", type=int, default=5, help="timed calls per big grid (>= 5)")
    p.add_argument("--theta-tol", type=float, default=60.0, help="cone half-angle, degrees")
    p.add_argument("--single-cpu", action="store_true",
                   help="pin the process to one CPU core before JAX starts (the paper's runs "
                        "are single-CPU; the reference is serial either way)")
    p.add_argument("--results-dir", type=Path, default=RESULTS_DIR,
                   help=f"where to write the results; default {RESULTS_DIR}")
    p.add_argument("--name", default=None,
                   help="results file stem; default 'fabric' ('fabric_quick' with --quick)")
    p.add_argument("--targets", action="store_true",
                   help="only print the targets line of the saved results (no benchmark run)")
    args = p.parse_args(argv)
    if args.quick:
        args.seeds = 1
        args.sizes = [25, 45, 65]
        args.big_sizes = [128, 256]
    if args.name is None:
        args.name = "fabric_quick" if args.quick else "fabric"
    if args.repeats < 5 or args.big_repeats < 5:
        p.error("--repeats and --big-repeats must be >= 5 (median of >= 5 timed calls)")
    if args.seeds < 1 or args.ref_repeats < 1:
        p.error("--seeds and --ref-repeats must be >= 1")
    if any(not 0.0 < d <= 1.0 for d in args.densities) or not 0.0 < args.big_density <= 1.0:
        p.error("densities must lie in (0, 1]")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    json_path = args.results_dir / f"{args.name}.json"
    md_path = args.results_dir / f"{args.name}.md"
    if args.targets:
        if not json_path.is_file():
            print(f"error: no saved results at {json_path}; run the benchmark first",
                  file=sys.stderr)
            return 2
        print(targets_line(json.loads(json_path.read_text())))
        return 0

    from jaxplan import FabricParams, single_cpu

    if args.single_cpu:
        try:
            single_cpu()   # before the first JAX computation, so XLA sizes its thread pool to one core
        except RuntimeError as exc:
            print(f"error: --single-cpu: {exc}", file=sys.stderr)
            return 2

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    params = FabricParams(theta_tol_deg=args.theta_tol)
    env = environment(args.single_cpu)
    log(f"jax {env['jax_version']} on {env['backend']} ({env['device']}), "
        f"{env['cpus_available']} core(s)")
    result = {"environment": env, "config": {
        "quick": args.quick, "seeds": args.seeds, "sizes": args.sizes, "densities": args.densities,
        "repeats": args.repeats, "ref_repeats": args.ref_repeats, "reference": not args.no_reference,
        "big_sizes": args.big_sizes, "big_density": args.big_density,
        "big_repeats": args.big_repeats, "theta_tol": args.theta_tol,
        "single_cpu": args.single_cpu, "bootstrap_resamples": N_BOOT,
        "scenes": "uniform random counts 1..6 at the density, central circle target "
                  "r = max(2.5, 0.1 n), cell size 1"}}
    t_start = time.perf_counter()
    if args.sizes:
        instances, summary, by_density = run_paper_grids(args, params, log)
        result["paper_grids"] = {"summary": summary, "by_density": by_density,
                                 "instances": instances}
    if args.big_sizes:
        rows, fit, method = run_big(args, params, log)
        result["big"] = {"rows": rows, "fit": fit, "memory_method": method}
    result["wall_s"] = time.perf_counter() - t_start
    result["targets"] = [{"target": t, "measured": m, "verdict": v}
                         for t, m, v in check_targets(result)]

    text = markdown(result)
    args.results_dir.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(result, indent=2) + "\n")
    md_path.write_text(text)
    print(text)
    print(targets_line(result))
    print(f"wrote {json_path} and {md_path} ({result['wall_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
