"""Where a coordinated fleet's planning time goes: its parts, timed on one mid-run state.

A coordinated fleet of N rovers runs ``--warmup`` steps on a built-in site (the fabric refreshed
selectively on the host after each push, the cached tasks it left unchanged kept, as ``run_fleet``
does). On the state reached, each part of the next planning is timed alone, compiled first, median
of ``--repeats`` calls: the choice of sources (``assign.choose_sources``, rate rule, the sources set
aside withheld), the path screen (``set_aside.path_blockers``), planning the sources that pass it
(``assign.plan_candidates`` with the cached tasks), the same with only two of its new sources (the
difference is what the others cost), the greedy assignment (``assign.assign_planned``), and the
whole step (``advance``) with the candidates stale (it plans) and fresh (it does not), beside one
warm full build of the fabric.
Planning works on fixed-size arrays: a task's route has S slots (``state.route_slots``) and its
footprint's core list C rows (``footprint.path_slots`` + S spline samples per step), whatever the
route's length; the table shows both beside the planned routes' lengths.
Writes ``experiments/results/NAME.{json,md}``.

    python -m experiments.fleet_plan_parts                          # site512, 64 rovers, 400 steps
    python -m experiments.fleet_plan_parts --site site128 --rovers 8 --warmup 100 --name parts_small
"""
from __future__ import annotations

import argparse
import datetime as _dt
import platform
import statistics
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from experiments.results_io import write_results
from jaxplan import FabricParams, SpillParams
from jaxplan.core import timed
from jaxplan.fleet import (
    SITES,
    FleetConfig,
    advance,
    assign,
    footprint,
    keep_tasks,
    max_rovers,
    motion,
    reset,
    route_slots,
    set_aside,
    site,
)
from jaxplan.transport import EpisodeParams, build_fabric, selective_rebuild
from jaxplan.transport.spillage import evaluator_for

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def _median_ms(fn, *args, repeats: int) -> float:
    """Median wall ms of ``fn(*args)``, called once first to compile."""
    jax.block_until_ready(fn(*args))
    return statistics.median(timed(fn, *args)[1] for _ in range(repeats))


def _warm_state(scene, n: int, steps: int, params, spill, episode, config, evaluator):
    """The state after ``steps`` steps of a coordinated fleet, refreshed on the host as ``run_fleet`` does."""
    step = jax.jit(advance, static_argnames=("config", "evaluator"))
    keep = jax.jit(keep_tasks)
    state = reset(scene, params, spill, episode, config, max_steps=10 * steps + 10, max_pushes=1_000_000)
    from tqdm.auto import tqdm

    for _ in tqdm(range(steps), desc=f"warm-up x{n}", unit="step", leave=False):
        before, old = state.scene.obj, state.fabric
        state, record = step(state, params, spill, episode, config=config, evaluator=evaluator)
        if bool(np.asarray(record.ended).any()):
            changed = (state.scene.obj != before) & ~state.scene.target_mask
            state = keep(state._replace(fabric=selective_rebuild(state.scene, params, old, changed)[0]), params, old,
                         before)
    return state


def measure(site_name: str, n: int, warmup: int, repeats: int) -> dict:
    scene = site(site_name)
    params, spill = FabricParams(), SpillParams()
    episode = EpisodeParams(max_pushes=0)
    evaluator = evaluator_for(spill)
    config = FleetConfig(n, "coordinated").resolved(scene.shape)
    state = _warm_state(scene, n, warmup, params, spill, episode, config, evaluator)
    idle = state.rovers.phase == motion.IDLE
    m = state.candidates.exists.shape[0]
    cap, clearance = config.walk_cap, config.clearance

    def choose(state):
        holds = set_aside.holding(state.aside, state.rovers.phase, state.rovers.task_step)
        idle = state.rovers.phase == motion.IDLE
        return assign.choose_sources(state.scene, episode, state.fabric, state.owner, m,
                                     assign.wanted_candidates(idle, config.candidates), (state.rovers.base, idle),
                                     set_aside.withheld(state.aside, holds, scene.shape))

    choose = jax.jit(choose)
    flat, exists = choose(state)
    screen = jax.jit(lambda s, flat, todo: set_aside.path_blockers(s.scene, s.fabric, s.owner, flat, todo, cap))
    passed = exists & (screen(state, flat, exists) < 0)

    def planner(short_cap):
        return jax.jit(lambda s, flat, todo: assign.plan_candidates(
            s.scene, params, episode, spill, s.fabric, s.owner, candidates=config.candidates, cap=cap,
            evaluator=evaluator, clearance=clearance, previous=s.candidates, chosen=(flat, todo), short_cap=short_cap))

    plan, plan_whole = planner(config.short_cap), planner(None)
    planned = plan(state, flat, passed)
    whole_cap = plan_whole(state, flat, passed)
    same = bool(np.array_equal(np.asarray(planned.exists), np.asarray(whole_cap.exists))
                and np.array_equal(np.asarray(planned.tasks.route.cells), np.asarray(whole_cap.tasks.route.cells)))
    new = int(assign.newly_planned(planned, state.candidates))
    # the same planning with only the first two of its new sources: the difference is what the others cost
    cached = np.asarray(state.candidates.tasks.source)[np.asarray(state.candidates.exists)]
    fresh = np.asarray(passed) & ~np.isin(np.asarray(flat), cached[:, 0] * scene.shape[1] + cached[:, 1])
    two = jnp.asarray(np.asarray(passed) & (~fresh | (np.cumsum(fresh) <= 2)))
    give = jax.jit(lambda s, p: assign.assign_planned(p, s.rovers.pos, s.rovers.phase == motion.IDLE, s.owner,
                                                      jnp.int32(1_000_000), s.rovers.route))
    whole = jax.jit(lambda s, fresh: advance(s._replace(fresh=fresh), params, spill, episode, config, evaluator))
    build = jax.jit(lambda s: build_fabric(s.scene, params))
    times = {
        "choose_sources": _median_ms(choose, state, repeats=repeats),
        "path_screen": _median_ms(screen, state, flat, exists, repeats=repeats),
        "plan_candidates": _median_ms(plan, state, flat, passed, repeats=repeats),
        "plan_two_new": _median_ms(plan, state, flat, two, repeats=repeats),
        "plan_whole_cap": _median_ms(plan_whole, state, flat, passed, repeats=repeats),
        "assign_planned": _median_ms(give, state, planned, repeats=repeats),
        "step_planning": _median_ms(whole, state, jnp.bool_(False), repeats=repeats),
        "step_fresh_candidates": _median_ms(whole, state, jnp.bool_(True), repeats=repeats),
        "full_build": _median_ms(build, state, repeats=repeats),
    }
    usable = np.asarray(planned.exists)
    lengths = np.asarray(planned.tasks.route.n_cells)[usable]
    s = route_slots(config, scene.shape)
    core = footprint.path_slots(s, scene.shape) + s * spill.samples_per_step
    return dict(site=site_name, n_rovers=n, warmup=warmup, idle=int(np.asarray(idle).sum()),
                chosen=int(np.asarray(exists).sum()), screened_out=int(np.asarray(exists & ~passed).sum()),
                newly_planned=new, ms=times, route_slots=s, core_rows=int(core), short_cap=config.short_cap,
                walk_cap=cap, same_tasks_whole_cap=same,
                route_cells_median=float(np.median(lengths)) if lengths.size else None,
                route_cells_max=int(lengths.max()) if lengths.size else None)


def markdown(result: dict, meta: str) -> str:
    ms = result["ms"]
    extra = result["newly_planned"] - 2
    per_task = (ms["plan_candidates"] - ms["plan_two_new"]) / extra if extra > 0 else None
    rows = [("choose the sources (rate rule)", ms["choose_sources"]),
            (f"screen their paths ({result['chosen']} chosen, {result['screened_out']} set aside)", ms["path_screen"]),
            (f"plan the others ({result['newly_planned']} new tasks)", ms["plan_candidates"]),
            ("plan the same with two new tasks only", ms["plan_two_new"]),
            (f"plan the same at the whole walk cap only ({result['walk_cap']}; the default tries "
             f"{result['short_cap']} first)", ms["plan_whole_cap"]),
            ("greedy assignment", ms["assign_planned"]),
            ("whole step, candidates stale (plans)", ms["step_planning"]),
            ("whole step, candidates fresh (no planning)", ms["step_fresh_candidates"]),
            ("full build of the fabric", ms["full_build"])]
    lines = ["# Fleet: where the planning time goes", "", meta, "",
             f"`{result['site']}`, {result['n_rovers']} coordinated rovers, the state after {result['warmup']} "
             f"steps ({result['idle']} idle). Median wall ms of each part, compiled first.", "",
             "| part | ms | / full build |", "|---|---:|---:|"]
    lines += [f"| {name} | {v:.2f} | {v / ms['full_build']:.3f} |" for name, v in rows]
    lengths = ("-" if result["route_cells_median"] is None
               else f"median {result['route_cells_median']:.0f}, max {result['route_cells_max']}")
    each = "-" if per_task is None else f"{per_task:.2f} ms"
    same = "the same tasks" if result["same_tasks_whole_cap"] else "DIFFERENT tasks"
    lines += ["", f"Per task planned beyond two: {each}. A task's arrays are sized for the walk cap: "
              f"{result['route_slots']} route slots and {result['core_rows']} footprint core rows, against "
              f"routes of {lengths} cells among the tasks planned here. Planned with a short walk first "
              f"({result['short_cap']}), they are planned at its size and padded; both ways planned {same}.", ""]
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.fleet_plan_parts",
                                     description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="examples:\n  python -m experiments.fleet_plan_parts\n"
                                            "  python -m experiments.fleet_plan_parts --site site128 --rovers 8 "
                                            "--warmup 100 --name parts_small")
    parser.add_argument("--site", default="site512", choices=SITES, help="a built-in fleet site; default site512")
    parser.add_argument("--rovers", type=int, default=64, help="fleet size; default 64")
    parser.add_argument("--warmup", type=int, default=400, help="steps run before the parts are timed; default 400")
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per part; default 7")
    parser.add_argument("--name", default="fleet_plan_parts", help="results file stem; default fleet_plan_parts")
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR, help="where the results go")
    args = parser.parse_args(argv)
    for name, value, low, high in (("--rovers", args.rovers, 1, max_rovers()), ("--warmup", args.warmup, 1, None),
                                   ("--repeats", args.repeats, 1, None)):
        if value < low or (high is not None and value > high):
            parser.error(f"{name} {value}: give an integer from {low}" + ("" if high is None else f" to {high}"))
    meta = (f"{_dt.datetime.now(_dt.UTC).isoformat(timespec='seconds')}, {platform.platform()}, "
            f"jax {jax.__version__} ({jax.default_backend()}), {platform.processor() or platform.machine()}.")
    result = measure(args.site, args.rovers, args.warmup, args.repeats)
    write_results(args.results_dir, args.name, {"meta": meta, "result": result}, markdown(result, meta))


if __name__ == "__main__":
    main()
