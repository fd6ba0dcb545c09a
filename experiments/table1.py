"""Table I of PushAround (Section IV-A.2), the 30-movable scene (IV-A.3) and the density sweep, in one harness.

Planners (same scenes, same MuJoCo world and contact models, same Eq. 7 success test):
``ours`` (``plan_pushes`` with every component), its four ablations (``SearchConfig`` switches:
``w/o presearch``, ``w/o ModeTable``, ``w/o quick-pass``, ``w/o reinsertion``) and the baselines of
``jaxplan.pusharound.baselines`` (``DFS-WCCG``, ``SL-Push (offline)``, ``SL-Push (sim)``, ``Rec-NAMO``).
Scenes: ``nominal`` (``nominal_scene(seed)``, 10-15 movables), ``dense30`` (``dense_scene(seed)``),
``density`` (``density_scene(seed, n)`` for n in ``--densities``), ``corridor`` (one blocker; smoke).

Per trial (one planner, scene, seed): the world and simulator are built outside the timer, a fresh
ModeTable is used, then the planner runs with ``--time-limit``. Recorded: success (the planner's; for
the open-loop baselines it includes their open-loop physics execution), planning time (wall clock:
includes the JAX compiles of the simulator's policy, about 2 s per batch size and scene on this CPU),
simulated pushes (rollouts during planning), expansions, pushes in the schedule, and execution time:
with ``--execute`` (default) the schedule of a successful plan is executed by
``jaxplan.pusharound.execution.execute_schedule`` (transitions + pushes + early stop, no replanning)
and its simulated seconds are reported with its own success; otherwise (or if that module is
missing) the schedule's summed Eq. 11 ``delta_T`` (``baselines.schedule_duration``).

Every trial is appended to ``<out>/table1_trials.jsonl`` as soon as it ends; a rerun skips trials
already there (resume). Then ``<out>/table1.json`` and ``<out>/table1.md`` are written from all
recorded trials, with the paper's numbers beside ours.

    python -m experiments.table1                           # 40 trials, all planners, nominal
    python -m experiments.table1 --planners ours --trials 40 --scenes nominal,dense30,density
    python -m experiments.table1 --quick                    # smoke run: corridor scene, 1 trial

The machine is a 2-core CPU shared with other agents: timings are noisy (said in the outputs).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from jaxplan.pusharound import (
    RankingParams,
    build_push_world,
    corridor_scene,
    dense_scene,
    density_scene,
    make_push_simulator,
    nominal_scene,
)
from jaxplan.pusharound.baselines import BASELINES, BaselineConfig, schedule_duration
from jaxplan.pusharound.search import SearchConfig, plan_pushes

RESULTS = Path(__file__).resolve().parent / "results"
SHARED_NOTE = ("2-core CPU, shared while the trials ran (two harness processes side by side, and other work): "
               "wall-clock times are noisy and pessimistic; compare ratios within this run only.")

# ---------------------------------------------------------------------------------------- paper data
# Copied from the seed text (ICRA version, Table I) and the RA-L version's table (MengGuo/push_around_tex,
# ral_tex/contents/experiment.tex). These are THE PAPER'S numbers, not ours. Strings keep the ">" bounds.
PAPER_TABLE1 = {
    "DFS-WCCG": {"success": 25.0, "pt": ">100.0", "et": 51.2, "sims": ">500", "pushes": 8.0},
    "SL-Push (offline)": {"success": 62.5, "pt": 0.06, "et": 44.1, "sims": 0.0, "pushes": 7.0},
    "SL-Push (sim)": {"success": 75.0, "pt": 18.2, "et": 64.6, "sims": 20.0, "pushes": 10.0},
    "Rec-NAMO": {"success": 37.5, "pt": 13.3, "et": 42.4, "sims": 0.0, "pushes": 7.0},
    "ours": {"success": 92.5, "pt": 10.3, "et": 28.6, "sims": 121.5, "pushes": 6.0},
    "w/o presearch": {"success": 85.0, "pt": 16.9, "et": 35.2, "sims": 178, "pushes": 7.0},
    "w/o ModeTable": {"success": 80.0, "pt": 15.1, "et": 33.4, "sims": 164, "pushes": 6.0},
    "w/o quick-pass": {"success": 90.0, "pt": 23.6, "et": 41.9, "sims": 208, "pushes": 6.0},
    "w/o reinsertion": {"success": 82.5, "pt": 12.8, "et": 31.1, "sims": 151, "pushes": 7.0},
}
PAPER_TABLE1_RAL_SUCCESS = {"DFS-WCCG": 25.0, "SL-Push (offline)": 62.5, "SL-Push (sim)": 75.0, "Rec-NAMO": 37.5,
                            "ours": 97.5, "w/o presearch": 82.5, "w/o ModeTable": 92.5, "w/o quick-pass": 90.0,
                            "w/o reinsertion": 85.0}
# Section IV-A.3 (Fig. 9): one run with 30 movables.
PAPER_DENSE30 = {"pt": 21.2, "et": 24.5, "sims": 312, "pushes": 7, "expansions": 10}
# RA-L density sweep, PushAround row per N (success %, planning time mean s, pushes mean; 10 trials each):
# MengGuo/push_around_tex data/density_scaling/paper_table_density.txt.
PAPER_DENSITY = {15: (100, 2.5, 3.5), 20: (100, 4.9, 5.8), 25: (100, 8.2, 7.9), 30: (100, 11.7, 10.5),
                 35: (100, 26.5, 16.6), 40: (100, 38.9, 20.7), 45: (100, 53.4, 26.1)}

ABLATIONS = {"ours": {}, "w/o presearch": {"presearch": False}, "w/o ModeTable": {"mode_table": False},
             "w/o quick-pass": {"quick_pass": False}, "w/o reinsertion": {"reinsertion": False}}
PLANNERS = list(BASELINES) + list(ABLATIONS)
SCENES = ("nominal", "dense30", "density", "corridor")
# The paper's protocol stops a search by its time limit alone; SearchConfig's default cap of 200
# expansions stopped a dense30 trial at 125 of its 180 s, so the harness lifts it.
HARNESS_MAX_EXPANSIONS = 1_000_000


def make_scene(kind: str, seed: int, n: int | None):
    if kind == "nominal":
        return nominal_scene(seed)
    if kind == "dense30":
        return dense_scene(seed)
    if kind == "density":
        return density_scene(seed, n)
    if kind == "corridor":
        return corridor_scene(seed)
    raise ValueError(f"--scenes: unknown scene {kind!r}; choose from {', '.join(SCENES)}.")


def run_planner(name: str, scene, world, sim, time_limit: float, seed: int):
    """One planning call; returns the SearchResult."""
    if name in ABLATIONS:
        cfg = SearchConfig(time_limit_s=time_limit, seed=seed, max_expansions=HARNESS_MAX_EXPANSIONS,
                           **ABLATIONS[name])
        return plan_pushes(scene, cfg, RankingParams(), world=world, sim=sim)
    return BASELINES[name](scene, BaselineConfig(time_limit_s=time_limit), world=world, sim=sim)


def _execute(scene, res, world):
    """(success, simulated seconds, reason, source) of executing a successful plan."""
    try:
        from jaxplan.pusharound.execution import execute_schedule  # noqa: PLC0415 (optional module)
    except ImportError:
        return None
    ex = execute_schedule(scene, res, world=world, replan=None)
    return bool(ex.success), float(ex.execution_time_s), str(ex.reason)


def _execute_with_replanning(scene, res, world, planner: str, time_limit: float, seed: int):
    """(success, simulated seconds, reason, replans) of executing a plan with online replanning, as
    ``jaxplan pusharound`` does: on a failed push the same planner plans again from the state reached
    (half the time limit, at least 5 s; at most ``ExecutionConfig.max_replans`` times)."""
    from jaxplan.pusharound.execution import execute_schedule  # noqa: PLC0415 (optional module)

    def replan(now):
        return run_planner(planner, now, None, None, max(5.0, 0.5 * time_limit), seed)

    ex = execute_schedule(scene, res, world=world, replan=replan)
    return bool(ex.success), float(ex.execution_time_s), str(ex.reason), int(ex.replans)


def run_trial(planner: str, kind: str, seed: int, n: int | None, time_limit: float, execute: bool,
              replan: bool = False) -> dict:
    scene = make_scene(kind, seed, n)
    world = build_push_world(scene)
    sim = make_push_simulator(world, "auto")
    t0 = time.perf_counter()
    res = run_planner(planner, scene, world, sim, time_limit, seed)
    wall = time.perf_counter() - t0
    rec = {"planner": planner, "scene": kind, "n_movables": len(scene.movables), "density_n": n, "seed": seed,
           "success": bool(res.success), "reason": res.reason, "planning_time_s": float(res.stats.planning_time_s),
           "wall_s": wall, "simulated_pushes": int(res.stats.simulated_pushes),
           "expansions": int(res.stats.expansions), "pushes": len(res.schedule),
           "schedule_duration_s": schedule_duration(world, res.schedule) if res.schedule else 0.0,
           "exec_success": None, "execution_time_s": None, "exec_reason": None, "et_source": "schedule_duration",
           "time_limit_s": time_limit}
    if res.success and execute and res.schedule:
        t1 = time.perf_counter()
        out = _execute(scene, res, world)
        if out is not None:
            rec.update(exec_success=out[0], execution_time_s=out[1], exec_reason=out[2], et_source="execute_schedule",
                       exec_wall_s=time.perf_counter() - t1)
        if replan and planner in ABLATIONS:
            t2 = time.perf_counter()
            ok, et, why, count = _execute_with_replanning(scene, res, world, planner, time_limit, seed)
            rec.update(replan_exec_success=ok, replan_execution_time_s=et, replan_exec_reason=why, replans=count,
                       replan_exec_wall_s=time.perf_counter() - t2)
    if rec["execution_time_s"] is None and res.success:
        rec["execution_time_s"] = rec["schedule_duration_s"]
    return rec


# ------------------------------------------------------------------------------------------ summary

def _ms(values) -> dict:
    v = np.asarray([x for x in values if x is not None], np.float64)
    if len(v) == 0:
        return {"mean": None, "std": None, "median": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std()), "median": float(np.median(v)), "n": int(len(v))}


def summarise(records: list) -> list:
    """One row per (planner, scene, density n): success rate, PT and #sims over all trials, ET and
    #pushes over successful ones."""
    groups: dict = {}
    for r in records:
        groups.setdefault((r["planner"], r["scene"], r.get("density_n")), []).append(r)
    order = {p: i for i, p in enumerate(PLANNERS)}
    rows = []
    for (planner, scene, n), rs in sorted(groups.items(), key=lambda kv: (SCENES.index(kv[0][1]) if kv[0][1] in SCENES
                                                                           else 9, kv[0][2] or 0,
                                                                           order.get(kv[0][0], 99))):
        ok = [r for r in rs if r["success"]]
        executed = [r for r in ok if r.get("exec_success") is not None]
        replanned = [r for r in ok if r.get("replan_exec_success") is not None]
        rows.append({
            "planner": planner, "scene": scene, "density_n": n, "trials": len(rs),
            "success_pct": 100.0 * len(ok) / len(rs),
            "exec_success_pct": ((100.0 * sum(r["exec_success"] for r in executed) / len(executed))
                                 if executed else None),
            "replan_exec_success_pct": (100.0 * sum(r["replan_exec_success"] for r in replanned) / len(replanned)
                                        if replanned else None),
            "replans": _ms([r["replans"] for r in replanned]),
            "planning_time_s": _ms([r["planning_time_s"] for r in rs]),
            "execution_time_s": _ms([r["execution_time_s"] for r in ok]),
            "et_source": sorted({r["et_source"] for r in ok}) if ok else [],
            "simulated_pushes": _ms([r["simulated_pushes"] for r in rs]),
            "pushes": _ms([r["pushes"] for r in ok]),
            "movables": _ms([r["n_movables"] for r in rs]),
            # what the row was measured under: a report of recorded trials (--report-only) may mix runs
            "time_limit_s": sorted({r["time_limit_s"] for r in rs}),
            "code": sorted({r.get("code", "") for r in rs}),
        })
    return rows


def _f(stat, digits=1):
    if stat["mean"] is None:
        return "-"
    return f"{stat['mean']:.{digits}f} ± {stat['std']:.{digits}f}"


def _paper(name: str, scene: str, n) -> str:
    if scene == "nominal" and name in PAPER_TABLE1:
        p = PAPER_TABLE1[name]
        return (f"{p['success']} / {PAPER_TABLE1_RAL_SUCCESS[name]} · {p['pt']} · {p['et']} · {p['sims']} · "
                f"{p['pushes']}")
    if scene == "dense30" and name == "ours":
        p = PAPER_DENSE30
        return f"solved (1 run) · {p['pt']} · {p['et']} · {p['sims']} · {p['pushes']}"
    if scene == "density" and name == "ours" and n in PAPER_DENSITY:
        s, pt, pu = PAPER_DENSITY[n]
        return f"{s} · {pt} · - · - · {pu}"
    return ""


def write_outputs(records: list, out: Path, args_dict: dict) -> dict:
    rows = summarise(records)
    doc = {"note": SHARED_NOTE, "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
           "args": args_dict, "rows": rows,
           "paper": {"table1_icra": PAPER_TABLE1, "table1_ral_success": PAPER_TABLE1_RAL_SUCCESS,
                     "dense30": PAPER_DENSE30, "density_pusharound_ral": {str(k): v for k, v in PAPER_DENSITY.items()}},
           "definitions": {"success_pct": "planner success (open-loop baselines: after their physics execution)",
                           "exec_success_pct": "successful plans whose schedule execute_schedule executed to Eq. 7 "
                                               "(no replanning)",
                           "replan_exec_success_pct": "successful plans executed to Eq. 7 with online replanning "
                                                      "(--replan; ours and the ablations; up to 3 replans)",
                           "planning_time_s": "wall clock over all trials (failures at their stop time)",
                           "execution_time_s": "over successful plans: execute_schedule's simulated seconds when "
                                               "et_source says so, else the schedule's summed Eq. 11 delta_T",
                           "simulated_pushes": "rollouts during planning, all trials",
                           "pushes": "schedule length, successful plans"},
           "trials_file": "table1_trials.jsonl"}
    (out / "table1.json").write_text(json.dumps(doc, indent=1))
    lines = ["# Table I: PushAround and baselines (ours vs the paper)", "",
             f"Generated by `experiments/table1.py` ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}). "
             f"{SHARED_NOTE}", "",
             "Ours: Succ. = planner success (%), Exec. = of those, executed to Eq. 7 by `execute_schedule` (%), "
             "+replan = the same with online replanning (`--replan`; '-' where not run), "
             "PT = planning time mean ± std over all trials (median), ET = execution time over successes, "
             "#Sims = rollouts in planning (all trials), #Pushes = schedule length (successes). "
             "Paper column: Succ. (ICRA / RA-L) · PT · ET · #Sims · #Pushes as printed in the paper "
             "(a laptop i7 with PyBullet; not comparable in absolute time).", "",
             "| Scene | Planner | Trials | Limit (s) | Succ. | Exec. | +replan | PT (s) | PT median | ET (s) | #Sims "
             "| #Pushes | Paper |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        scene = r["scene"] + (f" N={r['density_n']}" if r["density_n"] else "")
        ex = "-" if r["exec_success_pct"] is None else f"{r['exec_success_pct']:.0f}"
        rp = "-" if r["replan_exec_success_pct"] is None else f"{r['replan_exec_success_pct']:.0f}"
        med = r["planning_time_s"]["median"]
        limit = "/".join(f"{t:g}" for t in r["time_limit_s"])
        lines.append(f"| {scene} | {r['planner']} | {r['trials']} | {limit} | {r['success_pct']:.1f} | {ex} | {rp} | "
                     f"{_f(r['planning_time_s'])} | {med:.2f} | {_f(r['execution_time_s'])} | "
                     f"{_f(r['simulated_pushes'])} | {_f(r['pushes'])} | "
                     f"{_paper(r['planner'], r['scene'], r['density_n'])} |")
    (out / "table1.md").write_text("\n".join(lines) + "\n")
    return doc


# ------------------------------------------------------------------------------------------ main

def _code_version() -> str:
    """HEAD commit of the repository (+ "-dirty" with uncommitted changes), "" outside git."""
    import subprocess  # noqa: PLC0415
    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                              timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True,
                               text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""
    return head + ("-dirty" if dirty else "")


def _trial_key(r: dict) -> tuple:
    return (r["planner"], r["scene"], r.get("density_n"), int(r["seed"]))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m experiments.table1", description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=40, help="trials (seeds 0..T-1) per planner and scene")
    ap.add_argument("--planners", default=",".join(PLANNERS), help=f"comma list of {PLANNERS}")
    ap.add_argument("--scenes", default="nominal", help="comma list of nominal,dense30,density,corridor")
    ap.add_argument("--densities", default="15,20,25,30,35,40,45", help="movable counts of the density sweep")
    ap.add_argument("--time-limit", type=float, default=60.0, help="planning time limit per trial [s]")
    ap.add_argument("--no-execute", action="store_true", help="ET from the schedule, no execute_schedule run")
    ap.add_argument("--replan", action="store_true",
                    help="also execute successful plans of ours and the ablations with online replanning")
    ap.add_argument("--quick", action="store_true", help="smoke run: corridor scene, 1 trial, 20 s limit")
    ap.add_argument("--out", default=str(RESULTS), help="output folder")
    ap.add_argument("--seed0", type=int, default=0, help="first seed")
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--report-only", action="store_true", help="only rewrite table1.json/.md from the JSONL")
    args = ap.parse_args(argv)
    if args.quick:
        args.trials, args.scenes, args.time_limit = 1, "corridor", min(args.time_limit, 20.0)
    planners = [p.strip() for p in args.planners.split(",") if p.strip()]
    bad = [p for p in planners if p not in PLANNERS]
    if bad:
        raise ValueError(f"--planners: unknown {bad}; choose from {PLANNERS}.")
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    bad = [s for s in scenes if s not in SCENES]
    if bad:
        raise ValueError(f"--scenes: unknown {bad}; choose from {list(SCENES)}.")
    if args.trials < 1 or not args.time_limit > 0:
        raise ValueError("--trials must be >= 1 and --time-limit > 0.")
    densities = [int(x) for x in args.densities.split(",") if x.strip()]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    jsonl = out / "table1_trials.jsonl"
    records = [json.loads(line) for line in jsonl.read_text().splitlines() if line.strip()] if jsonl.exists() else []
    done = {_trial_key(r) for r in records}
    # Trials interleave planners per seed, so an interrupted run has comparable counts for every planner.
    todo = [] if args.report_only else [
            (p, s, n, seed) for s in scenes for n in (densities if s == "density" else [None])
            for seed in range(args.seed0, args.seed0 + args.trials) for p in planners
            if (p, s, n, seed) not in done]
    from tqdm import tqdm  # noqa: PLC0415
    bar = tqdm(todo, desc="table1", disable=args.no_progress, dynamic_ncols=True)
    for planner, kind, n, seed in bar:
        bar.set_postfix_str(f"{planner} {kind}{'' if n is None else n} seed {seed}")
        rec = run_trial(planner, kind, seed, n, args.time_limit, not args.no_execute, args.replan)
        rec["utc"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        rec["code"] = _code_version()
        with jsonl.open("a") as fh:
            fh.write(json.dumps(rec) + "\n")
        records.append(rec)
    wanted = {(p, s) for p in planners for s in scenes}
    # a report of recorded trials has no run settings of its own: each row names its time limits and code
    settings = {"report_only": True} if args.report_only else vars(args)
    doc = write_outputs([r for r in records if (r["planner"], r["scene"]) in wanted] if args.quick else records, out,
                        settings)
    print((out / "table1.md").read_text())
    return doc


if __name__ == "__main__":
    main()
