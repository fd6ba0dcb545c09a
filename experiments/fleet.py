"""The fleet against one rover: T50 / T90, speed-up, delivered per rover-step, conflicts, planning time.

For every site and fleet size N and strategy, ``run_fleet`` runs until the mass outside the targets is
at most 2% of its start or ``--max-steps`` pass. Speed-up S(N) = T90(1) / T90(N) within a strategy
(T90: the first step by which 90% of the mass that started outside the targets was delivered; "-"
when not reached). Times, over every step (``summary.json``): step ms (the whole step), plan ms
(everything but the shared fabric's refresh: assignment, distance fields, motion, the pushes) and
refresh ms, median (and p95), beside one warm full build of the site's fabric measured in the same
process (``FleetRun.full_build_ms``), and plan / build, their ratio.
Writes ``experiments/results/NAME.{json,md}`` (``--name``, default fleet) after every run.

    python -m experiments.fleet                                   # site128, N = 1, 2, 4, 8
    python -m experiments.fleet --sites site128 site256 --rovers 1 2 4 8 16 32 64
    python -m experiments.fleet --quick                           # a 24x24 piles scene, N = 1, 2
"""
from __future__ import annotations

import argparse
import datetime as _dt
import platform
import statistics
import time
from pathlib import Path

import jax

from experiments.results_io import write_results
from jaxplan import FabricParams, random_scene
from jaxplan.fleet import STRATEGIES, FleetConfig, run_fleet, site, summary_of
from jaxplan.transport import EpisodeParams

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def _row(name, scene, n, strategy, params, episode, max_steps, candidates_by="rate", set_aside=True,
         walk_cap=None, short_cap=None) -> dict:
    start = time.perf_counter()
    config = FleetConfig(n, strategy, candidates_by=candidates_by, set_aside=set_aside, walk_cap=walk_cap,
                         short_cap=short_cap)
    run = run_fleet(scene, n, strategy, params, episode=episode, max_steps=max_steps, progress=True, config=config)
    wall = time.perf_counter() - start
    s = summary_of(run)
    label = strategy if strategy != "coordinated" else \
        f"coordinated ({candidates_by}{'' if set_aside else ', no set-aside'})"
    if walk_cap is not None:
        label += f", walk cap {walk_cap}"
    if short_cap is not None and strategy == "coordinated":
        label += f", short walk {short_cap}"
    return {"site": name, "rovers": n, "strategy": label, "T50": s["T50"], "T90": s["T90"], "steps": s["steps"],
            "pushes": s["pushes"], "delivered": s["delivered"], "outside_start": s["initial_outside"],
            "delivered_per_rover_step": s["delivered_per_rover_step"],
            "conflicts": s["conflicts"], "step_ms": s["step_ms"], "plan_ms": s["plan_ms"],
            "refresh_ms": s["refresh_ms"], "full_build_ms": s["full_build_ms"],
            "idle_fraction_mean": statistics.fmean(s["idle_fraction"]), "made_way": s["made_way"],
            "tasks_planned": s["tasks_planned"], "plan_ms_planning": s["plan_ms_planning"],
            "plan_ms_not_planning": s["plan_ms_not_planning"],
            "stop_reason": s["stop_reason"], "wall_s": round(wall, 2)}


def _rate(r) -> float:
    """Objects delivered per step over the run."""
    return r["delivered"] / max(r["steps"], 1)


def _median(d) -> str:
    return "-" if d["median"] is None else f"{d['median']:.1f}"


def _markdown(rows, meta) -> str:
    t90_one = {(r["site"], r["strategy"]): r["T90"] for r in rows if r["rovers"] == 1}
    one = {(r["site"], r["strategy"]): r for r in rows if r["rovers"] == 1}
    lines = [f"# Fleet: T90, speed-up and planning time\n\n{meta}\n",
             "S(N) = T90(1) / T90(N); rate x = objects delivered per step against one rover's, both over "
             "their whole runs (the speed-up where a run stopped at the step limit before T90); plan / 1: "
             "median plan ms against one rover's; tasks planned / push: the tasks the coordinated assignments "
             "planned per push applied; plan ms planning / not: median plan ms of the steps that planned a task "
             "and of the others.\n",
             "| site | strategy | N | steps | delivered | T50 | T90 | S(N) | rate x | delivered / rover-step | "
             "idle (mean) | made way | conflicts | step ms (median, p95) | plan ms (median, p95) | "
             "refresh ms (median, p95) | "
             "full build ms | plan / build | plan / 1 | tasks planned / push | plan ms planning / not | stop |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]

    def both(d):
        return "-" if d["median"] is None else f"{d['median']:.1f}, {d['p95']:.1f}"

    for r in rows:
        t90 = t90_one.get((r["site"], r["strategy"]))
        speed = f"{t90 / r['T90']:.2f}" if t90 and r["T90"] else "-"
        single = one.get((r["site"], r["strategy"]))
        rate = f"{_rate(r) / _rate(single):.2f}" if single and _rate(single) > 0 else "-"
        alone = single["plan_ms"]["median"] if single else None
        per_one = "-" if r["plan_ms"]["median"] is None or not alone else f"{r['plan_ms']['median'] / alone:.2f}"
        build = r["full_build_ms"]
        ratio = "-" if r["plan_ms"]["median"] is None or not build else f"{r['plan_ms']['median'] / build:.2f}"
        per_push = f"{r['tasks_planned'] / r['pushes']:.2f}" if r.get("tasks_planned") is not None and r["pushes"] \
            else "-"
        split = "-" if "plan_ms_planning" not in r else \
            f"{_median(r['plan_ms_planning'])} / {_median(r['plan_ms_not_planning'])}"
        lines.append(f"| {r['site']} | {r['strategy']} | {r['rovers']} | {r['steps']} | {r['delivered']:.0f} | "
                     f"{r['T50'] or '-'} | {r['T90'] or '-'} | {speed} | {rate} | "
                     f"{r['delivered_per_rover_step']:.3f} | {r['idle_fraction_mean']:.0%} | "
                     f"{r.get('made_way', '-')} | "
                     f"{r['conflicts']} | "
                     f"{both(r['step_ms'])} | {both(r['plan_ms'])} | {both(r['refresh_ms'])} | {build or 0:.2f} | "
                     f"{ratio} | {per_one} | {per_push} | {split} | {r['stop_reason']} |")
    return "\n".join(lines) + "\n"


def _set_aside_modes(choice: str, strategy: str) -> tuple:
    """The ``FleetConfig.set_aside`` values to run: the other strategies plan no candidates."""
    if strategy != "coordinated":
        return (True,)
    return {"on": (True,), "off": (False,), "both": (True, False)}[choice]


def _lengths(parser, flag: str, values) -> list:
    """The walk lengths of ``flag`` (positive ints, None for 'default'); a bad one exits 2."""
    try:
        lengths = [None if v == "default" else int(v) for v in values]
    except ValueError:
        lengths = [0]
    if any(v is not None and v < 1 for v in lengths):
        parser.error(f"{flag} {' '.join(values)}: give positive integers or 'default'")
    return lengths


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.fleet", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="examples:\n  python -m experiments.fleet\n"
                                            "  python -m experiments.fleet --sites site128 --rovers 1 2 4 8 "
                                            "--strategies coordinated\n  python -m experiments.fleet --quick")
    parser.add_argument("--sites", nargs="+", default=["site128"], help="built-in fleet sites; default site128")
    parser.add_argument("--rovers", nargs="+", type=int, default=[1, 2, 4, 8], help="fleet sizes; default 1 2 4 8")
    parser.add_argument("--strategies", nargs="+", default=list(STRATEGIES), choices=STRATEGIES)
    parser.add_argument("--candidates-by", choices=("value", "rate"), default="rate",
                        help="the coordinated strategy's candidates (FleetConfig.candidates_by); default rate")
    parser.add_argument("--set-aside", choices=("on", "off", "both"), default="on",
                        help="the coordinated strategy's set-aside list (FleetConfig.set_aside); both: a run "
                             "with and one without, side by side; default on")
    parser.add_argument("--walk-cap", nargs="+", default=["default"],
                        help="static walk lengths of the fleet's plans (FleetConfig.walk_cap), each run side by "
                             "side; 'default': episode.default_walk_cap, 4 (H + W) on large grids; default: default")
    parser.add_argument("--short-cap", nargs="+", default=["default"],
                        help="walk lengths the coordinated planning tries first (FleetConfig.short_cap), each run "
                             "side by side; one at least the walk cap plans every task at the walk cap; "
                             "'default': 128 on grids whose walk cap is 512 or more; default: default")
    parser.add_argument("--max-steps", type=int, default=20_000, help="step limit per run; default 20000")
    parser.add_argument("--stop-fraction", type=float, default=0.02,
                        help="stop once this fraction of the mass that started outside the targets is left; "
                             "0.1 stops at T90; default 0.02")
    parser.add_argument("--quick", action="store_true", help="a 24x24 piles scene, N = 1 and 2 (a smoke test)")
    parser.add_argument("--name", default="fleet", help="results file stem; default fleet")
    args = parser.parse_args(argv)
    caps = _lengths(parser, "--walk-cap", args.walk_cap)
    shorts = _lengths(parser, "--short-cap", args.short_cap)
    if args.quick:
        scenes = {"piles24": random_scene(0, (24, 24), layout="piles")}
        args.rovers, args.max_steps = [1, 2], 2000
    else:
        scenes = {name: site(name) for name in args.sites}
    params, episode = FabricParams(), EpisodeParams(max_pushes=1_000_000, stop_fraction=args.stop_fraction)
    meta = (f"{_dt.datetime.now(_dt.UTC).isoformat(timespec='seconds')}, {platform.platform()}, "
            f"jax {jax.__version__} ({jax.default_backend()}), {platform.processor() or platform.machine()}; "
            f"stop at {args.stop_fraction:.0%} of the mass outside the targets or {args.max_steps} steps.")
    rows = []
    for name, scene in scenes.items():
        for strategy in args.strategies:
            for n in args.rovers:
                for aside in _set_aside_modes(args.set_aside, strategy):
                    for cap in caps:
                        for short in shorts:
                            rows.append(_row(name, scene, n, strategy, params, episode, args.max_steps,
                                             args.candidates_by, aside, cap, short))
                            # rewritten after every run: an interrupted benchmark keeps the rows it finished
                            write_results(RESULTS_DIR, args.name, {"meta": meta, "rows": rows},
                                          _markdown(rows, meta))


if __name__ == "__main__":
    main()
