"""Monte-Carlo of the earthmoving team organization over randomised sites.

Draws ``--sites`` sites with ``jaxplan.teams.random_sites`` (two loading sites of 4-14 t, routes of
80-250 m, trucks at 60-100% of their 4 m/s spec, a velocity drop on 70% of the sites, a slower
excavator on 30%, a truck failure on 30%; 10 trucks; deadline 900 s) and simulates every site under
each strategy, all sites at once (``run_sites``: ``vmap`` over a ``lax.scan``):

- performance: the paper's coordinators (Eqs. 1-4, error correction, blackboard transfers);
- even: fixed even split of the trucks, re-dealt only when a site is cleared;
- largest: every truck to the largest unfinished site (then to the next);
- oracle: the coordinators' rules with the true loads and loading times and the worst velocity
  still to come (it knows the future velocities, not the failures).

Per strategy: deadline-met rate (both sites cleared by 900 s) with a 95% Wilson interval, trucks
used (peak at once; truck-seconds until all soil is delivered), time at which the last site was
cleared, and the run time. Timing: the compile (``jit(...).lower(...).compile()``) is reported
separately from the run (median of ``--repeats`` calls of the compiled function, each ended by
``block_until_ready``). With ``--devices 2`` (the default) XLA splits the CPU into two host devices
and the batch is sharded across them, one per core.

Results: ``experiments/results/teams_montecarlo.json`` and ``.md`` (``teams_montecarlo_quick`` with
``--quick``).

Examples::

    python -m experiments.teams_montecarlo              # 10,000 sites
    python -m experiments.teams_montecarlo --quick      # 500 sites, smoke run
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import sys
import time
from pathlib import Path

RESULTS_DIR = Path(__file__).resolve().parent / "results"
TARGET_S = 10.0
TARGET_SITES = 10_000


def _parse(argv):
    ap = argparse.ArgumentParser(prog="python -m experiments.teams_montecarlo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--sites", type=int, default=TARGET_SITES, help="number of random sites")
    ap.add_argument("--seed", type=int, default=0, help="seed of the site draws")
    ap.add_argument("--steps", type=int, default=1350, help="steps of 1 s (deadline 900 s + 450)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per strategy (median)")
    ap.add_argument("--devices", type=int, default=2, help="host devices to shard the batch over")
    ap.add_argument("--quick", action="store_true", help="500 sites, 1 repeat")
    args = ap.parse_args(argv)
    if args.quick:
        args.sites, args.repeats = 500, 1
    if args.sites < 1 or args.steps < 1 or args.repeats < 1 or args.devices < 1:
        ap.error("--sites, --steps, --repeats and --devices must be >= 1")
    return args


def wilson(k: int, n: int, z: float = 1.96):
    """Wilson 95% interval of a rate k / n."""
    import math

    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def _shard(params, n_devices: int):
    """Split the batch axis across the host devices when it divides evenly; else leave it."""
    import jax
    from jax.sharding import NamedSharding, PartitionSpec

    batch = params.mass.shape[0]
    if n_devices < 2 or batch % n_devices:
        return params, 1
    mesh = jax.make_mesh((n_devices,), ("sites",), axis_types=(jax.sharding.AxisType.Auto,))
    return jax.device_put(params, NamedSharding(mesh, PartitionSpec("sites"))), n_devices


def _summary(res, deadline: float) -> dict:
    import numpy as np

    met = np.asarray(res.met)
    clear = np.asarray(res.clear_time)
    last_clear = np.where(np.all(np.isfinite(clear), axis=1), np.nanmax(clear, axis=1), np.nan)
    n = met.size
    lo, hi = wilson(int(met.sum()), n)
    cleared = np.isfinite(last_clear)
    return {
        "met_rate": float(met.mean()), "met_ci95": [lo, hi],
        "peak_trucks_mean": float(np.asarray(res.peak_trucks).mean()),
        "truck_seconds_mean": float(np.asarray(res.truck_seconds).mean()),
        "last_clear_s_median": float(np.median(last_clear[cleared])) if cleared.any() else None,
        "cleared_in_horizon_rate": float(cleared.mean()),
        "late_by_s_median": (float(np.median(last_clear[cleared & ~met] - deadline))
                             if (cleared & ~met).any() else None),
        "lost_kg_mean": float(np.asarray(res.lost).sum(axis=1).mean()),
    }


def main(argv=None) -> int:
    args = _parse(argv)
    if args.devices > 1:  # must be set before jax is imported
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                                   f" --xla_force_host_platform_device_count={args.devices}")
    import jax
    import numpy as np

    from jaxplan.teams import STRATEGIES, TeamsConfig, random_sites, run_sites_jit, validate_site

    sites = random_sites(args.seed, args.sites)
    cfg0 = TeamsConfig(n_trucks=10, n_steps=args.steps)
    validate_site(sites, cfg0)
    params, used_devices = _shard(sites, min(args.devices, jax.device_count()))
    rows = {}
    for strategy in STRATEGIES:
        cfg = cfg0.replace(strategy=strategy)
        start = time.perf_counter()
        compiled = run_sites_jit.lower(cfg, params).compile()
        compile_s = time.perf_counter() - start
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            res, _ = jax.block_until_ready(compiled(params))
            times.append(time.perf_counter() - start)
        row = _summary(jax.device_get(res), float(sites.deadline[0]))
        row.update(compile_s=compile_s, run_s_median=float(np.median(times)),
                   run_s_all=[float(t) for t in times])
        rows[strategy] = row
        print(f"{strategy:12s} met {row['met_rate']:.3f}  peak trucks {row['peak_trucks_mean']:.2f}  "
              f"run {row['run_s_median']:.2f} s  compile {compile_s:.2f} s", flush=True)

    perf = rows["performance"]
    out = {
        "experiment": "teams_montecarlo",
        "date": _dt.datetime.now().isoformat(timespec="seconds"),
        "sites": args.sites, "seed": args.seed, "steps": args.steps, "dt_s": 1.0,
        "deadline_s": float(sites.deadline[0]), "n_trucks": 10, "n_teams": 2,
        "devices": used_devices, "repeats": args.repeats,
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "python": sys.version.split()[0], "jax": jax.__version__,
                    "backend": jax.default_backend()},
        "strategies": rows,
        "target": {"sites": TARGET_SITES, "seconds": TARGET_S,
                   "met": bool(args.sites >= TARGET_SITES and perf["run_s_median"] < TARGET_S)},
    }
    name = "teams_montecarlo_quick" if args.quick else "teams_montecarlo"
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    (RESULTS_DIR / f"{name}.json").write_text(json.dumps(out, indent=2) + "\n")
    md = _markdown(out)
    (RESULTS_DIR / f"{name}.md").write_text(md)
    print(md)
    return 0


def _markdown(out: dict) -> str:
    fmt = lambda x, f="{:.0f}": "-" if x is None else f.format(x)  # noqa: E731
    lines = [
        "# Earthmoving team organization: Monte-Carlo",
        "",
        f"{out['sites']:,} random sites (seed {out['seed']}), 2 loading sites, 10 trucks, deadline "
        f"{out['deadline_s']:.0f} s, {out['steps']} steps of {out['dt_s']:g} s; "
        f"{out['devices']} host device(s); jax {out['machine']['jax']} on "
        f"{out['machine']['cpus']} CPUs. Met = both sites cleared by the deadline.",
        "",
        "| strategy | deadline met [95% CI] | peak trucks (mean) | truck-seconds (mean) | "
        "last site cleared, median s | late sites: median s late | run s (median) | compile s |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in out["strategies"].items():
        lo, hi = r["met_ci95"]
        lines.append(
            f"| {name} | {r['met_rate']:.3f} [{lo:.3f}, {hi:.3f}] | {r['peak_trucks_mean']:.2f} | "
            f"{r['truck_seconds_mean']:.0f} | {fmt(r['last_clear_s_median'])} | "
            f"{fmt(r['late_by_s_median'])} | {r['run_s_median']:.2f} | {r['compile_s']:.2f} |")
    t = out["target"]
    run = out["strategies"]["performance"]["run_s_median"]
    lines += ["", f"Target: {t['sites']:,} sites in under {t['seconds']:g} s (run, excluding "
              f"compile): performance strategy {run:.2f} s for {out['sites']:,} sites -> "
              f"{'met' if t['met'] else 'not met'}.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
