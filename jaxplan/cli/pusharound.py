"""The ``pusharound`` subcommand: plan and execute pushes that open a W-clear corridor."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from jaxplan.cli.common import FPS, SEED, CLIError, check_out_dir, cli_path_kind, ranged, run_folder, wrap
from jaxplan.core import atomic_write

PUSHAROUND_RESULT_FORMAT = "jaxplan.pusharound.result"
MAX_TIME_LIMIT = 86_400.0   # s: a day; the search's result does not improve much after minutes
MAX_REPLANS = 100           # each replan searches again for up to max(5, time_limit / 2) s
MAX_FRAMES = 10_000         # rendered one by one (about 0.1 s each) into one GIF


def _pusharound_scene(args):
    """The scene of ``--scene`` (a JSON file) or the built-in ``nominal_scene(--seed)``."""
    from jaxplan.pusharound import PushScene, nominal_scene

    if args.scene is None:
        return nominal_scene(args.seed), f"nominal_scene(seed={args.seed})"
    path = Path(args.scene)
    if cli_path_kind(path, "--scene") == "missing":
        raise CLIError(f"--scene: no such scene file {args.scene!r} (a PushAround scene .json, see "
                       "docs/pusharound.md; leave --scene out for the built-in nominal scene).")
    try:
        return PushScene.load(path), str(path)
    except ValueError as exc:  # PushScene.load names the file and what is wrong with it
        raise CLIError(f"--scene: {exc}") from None


def _mode_table(name):
    """The table of ``--mode-table`` (read if the file exists, else empty), or None without the flag.

    The file is written after planning, so its folder must exist and the path must not be a directory.
    """
    from jaxplan.pusharound import ModeTable

    if name is None:
        return None
    path = Path(name)
    kind = cli_path_kind(path, "--mode-table")
    if kind == "dir":
        raise CLIError(f"--mode-table: {name!r} is a directory; give a .json file (read if it exists, "
                       "saved after the run).")
    if kind == "missing":
        if cli_path_kind(path.absolute().parent, "--mode-table") != "dir":
            raise CLIError(f"--mode-table: the folder {str(path.parent)!r} does not exist; create it or "
                           "pick another path for the table.")
        check_out_dir(str(path.absolute().parent), "--mode-table")   # it is saved there after planning
        return ModeTable()
    try:
        return ModeTable.load(path)
    except ValueError as exc:  # ModeTable.load names the file and what is wrong with it
        raise CLIError(f"--mode-table: {exc}") from None


def _check_feasible(args, scene) -> None:
    """Geometry no push can change (``jaxplan.pusharound.check_feasible``), before any work."""
    from jaxplan.pusharound import check_feasible

    try:
        check_feasible(scene)
    except ValueError as exc:
        where = f"--scene: {args.scene}" if args.scene is not None else f"--seed: nominal_scene({args.seed})"
        raise CLIError(f"{where}: {exc}") from None


def _xy(a) -> list:
    return np.round(np.asarray(a, np.float64), 6).tolist()


def _push_record(scene, k: int, item) -> dict:
    """One scheduled push in world coordinates (contacts and push directions at the pose before)."""
    t = item.task
    m = int(np.asarray(t.movable))
    x, y, psi = (float(v) for v in np.asarray(item.poses_before)[m])
    rot = np.array([[np.cos(psi), -np.sin(psi)], [np.sin(psi), np.cos(psi)]])
    active = np.asarray(t.active, bool)
    return {"index": k, "movable": m, "name": scene.movables[m].name,
            "gap": [int(v) for v in np.atleast_1d(item.gap)] if item.gap is not None else None,
            "active_robots": np.nonzero(active)[0].tolist(),
            "contacts_world": _xy(np.asarray(t.contacts) @ rot.T + np.array([x, y]))[:],
            "directions_world": _xy(np.asarray(t.directions) @ rot.T),
            "contacts_body": _xy(t.contacts), "directions_body": _xy(t.directions), "active": active.tolist(),
            "velocity": _xy(t.velocity), "duration_s": float(np.asarray(t.duration)), "cost": float(item.cost),
            "target_before": _xy(np.asarray(item.poses_before)[m]),
            "target_after": _xy(np.asarray(item.poses_after)[m]),
            "poses_before": _xy(item.poses_before), "poses_after": _xy(item.poses_after),
            "robots_before": _xy(item.robots_before), "robots_after": _xy(item.robots_after)}


def _obstacle_records(scene) -> list:
    """Every movable (at its pose) and fixed obstacle: world outline (exterior + holes) and convex pieces."""
    def rings(poly):
        parts = list(getattr(poly, "geoms", [poly]))
        main = max(parts, key=lambda g: g.area)
        return (_xy(np.asarray(main.exterior.coords)[:, :2]),
                [_xy(np.asarray(h.coords)[:, :2]) for h in main.interiors], len(parts))

    out = []
    for i, m in enumerate(scene.movables):
        ext, holes, n = rings(m.polygon)
        out.append({"kind": "movable", "index": i, "name": m.name, "pose": _xy(m.pose), "mass": float(m.mass),
                    "polygon": ext, "holes": holes,
                    "pieces": [_xy(np.asarray(p.exterior.coords)[:, :2]) for p in m.world_pieces()]})
    for i, f in enumerate(scene.fixed):
        ext, holes, n = rings(f.polygon)
        out.append({"kind": "fixed", "index": i, "name": f.name, "polygon": ext, "holes": holes,
                    "pieces": [_xy(np.asarray(p.exterior.coords)[:, :2]) for p in f.world_pieces()]})
    return out


def _pusharound_result(scene, source, args, *, plan=None, execution=None, final=None, path=None, connected=None,
                       success=False, reason="", error=None, final_check=None) -> dict:
    """The content of result.json (docs/pusharound.md, "Execution and CLI")."""
    final = scene if final is None else final
    stats = plan.stats._asdict() if plan is not None and hasattr(plan.stats, "_asdict") else None
    out = {
        "format": PUSHAROUND_RESULT_FORMAT, "version": 1,
        "success": bool(success), "reason": reason,
        "W": float(scene.width), "start": _xy(scene.start), "goal": _xy(scene.goal),
        "workspace": _xy(scene.workspace), "robot_radius": float(scene.robot_radius),
        "scene": {"source": source, "movables": len(scene.movables), "fixed": len(scene.fixed),
                  "robots": int(np.asarray(scene.robots).reshape(-1, 2).shape[0])},
        "planning": None if plan is None else {
            "success": bool(plan.success), "reason": plan.reason, "pushes": len(plan.schedule),
            "backend": args.backend, "time_limit_s": args.time_limit, "seed": args.seed,
            "stats": {k: (round(v, 4) if isinstance(v, float) else v) for k, v in (stats or {}).items()}},
        "schedule": [] if plan is None else [_push_record(scene, k, s) for k, s in enumerate(plan.schedule)],
        "execution": None,
        "final_state": "execution" if execution is not None else ("plan" if plan is not None else "initial"),
        "connectivity": connected,
        "obstacles": _obstacle_records(final),
        "robots_final": _xy(np.asarray(final.robots).reshape(-1, 2)),
        "w_clear_path": None if path is None else _xy(path),
        "scene_final_check": final_check,
    }
    if execution is not None:
        out["execution"] = {
            "success": bool(execution.success), "reason": execution.reason, "replans": int(execution.replans),
            "execution_time_s": round(float(execution.execution_time_s), 4),
            "pushes": [{"index": k, "movable": int(np.asarray(e.task.movable)),
                        "name": scene.movables[int(np.asarray(e.task.movable))].name, "plan": int(e.plan),
                        "stop": e.stop, "valid": bool(e.valid), "invalid": e.invalid, "ok": bool(e.ok),
                        "deviation_m": None if not np.isfinite(e.deviation) else round(float(e.deviation), 5),
                        "transit_s": round(float(e.transit_s), 4), "push_s": round(float(e.push_s), 4),
                        "active_robots": np.nonzero(np.asarray(e.task.active))[0].tolist(),
                        "velocity": _xy(e.task.velocity),
                        "target_planned": _xy(e.planned[int(np.asarray(e.task.movable))]),
                        "target_after": _xy(e.poses_after[int(np.asarray(e.task.movable))])}
                       for k, e in enumerate(execution.executed)]}
    if error is not None:
        out["error"] = error
    return out


def _cmd_pusharound(args) -> int:
    import matplotlib

    matplotlib.use("Agg")

    scene, source = _pusharound_scene(args)
    _check_feasible(args, scene)
    table = _mode_table(args.mode_table)
    with run_folder(args) as run:
        plan, execution, success, path = _plan_execute_write(args, scene, source, table, run)

    st = plan.stats
    print(f"plan: {'success' if plan.success else 'failed (' + plan.reason + ')'}, {len(plan.schedule)} pushes, "
          f"{st.planning_time_s:.1f} s planning, {st.expansions} expansions, {st.simulated_pushes} simulated pushes")
    if execution is not None:
        print(f"execution: {'success' if execution.success else 'failed'} ({execution.reason}), "
              f"{len(execution.executed)} pushes, {execution.replans} replans, "
              f"{execution.execution_time_s:.1f} s simulated")
    print(f"result: {'success' if success else 'no corridor'}" + ("" if path is None else
                                                                  f", W-clear path of {len(path)} points"))
    for name in run.files:
        print(f"wrote {run.path / name}")
    return 0




def _plan_execute_write(args, scene, source, table, run):
    """Plan, execute (unless --no-execute) and write the outputs into ``run``; result.json exists from
    the start and is rewritten at each stage. Returns (plan, execution or None, success, path)."""
    import threading
    from types import SimpleNamespace

    from tqdm import tqdm

    from jaxplan.pusharound import (
        PushScene,
        animate_execution,
        build_push_world,
        build_wccg,
        connectivity,
        save_final_png,
        w_clear_path,
    )
    from jaxplan.pusharound.execution import ExecutionConfig, execute_schedule, plan_frames
    from jaxplan.pusharound.search import SearchConfig, plan_pushes

    def write_result(**kw):
        try:
            run.write_json("result.json", _pusharound_result(scene, source, args, **kw))
        except OSError as exc:
            raise CLIError(f"--out: could not write into {str(run.path)!r} ({exc.strerror or exc}).") from None

    config = SearchConfig(time_limit_s=float(args.time_limit), backend=args.backend, seed=int(args.seed))
    can_push = bool(scene.movables) and np.asarray(scene.robots).size > 0
    world = build_push_world(scene) if can_push else None   # nothing to push (check_feasible): no physics
    bar = tqdm(total=round(float(args.time_limit), 1), desc="planning", unit="s", file=sys.stderr, leave=False,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.0f} s of the time limit{postfix}")

    started = time.perf_counter()
    done = threading.Event()

    def progress(info: dict):
        bar.set_postfix_str(f"expansions {info.get('expansions', 0)}, simulated {info.get('simulated_pushes', 0)}, "
                            f"queue {info.get('queue', 0)}", refresh=False)

    def clock():
        # The search reports after each expansion (seconds apart): a clock keeps the bar moving between.
        while not done.wait(0.5):
            bar.n = min(bar.total, round(time.perf_counter() - started, 1))
            bar.refresh()

    ticker = threading.Thread(target=clock, daemon=True)
    write_result(reason="planning")             # a result.json exists from the start
    try:
        ticker.start()
        plan = plan_pushes(scene, config, world=world, mode_table=table, progress=progress)
    except KeyboardInterrupt:
        write_result(reason="interrupted while planning")
        raise
    except Exception as exc:                      # an internal failure: keep a record, then show it
        write_result(reason="planning raised", error=f"{type(exc).__name__}: {exc}")
        raise
    finally:
        done.set()
        ticker.join()
        bar.close()
    if table is not None:
        atomic_write(Path(args.mode_table), lambda fh: fh.write(json.dumps(table.to_dict(), indent=1).encode()))

    def conn_and_path(s):
        g = build_wccg(s)
        ok = bool(connectivity(g, s.start, s.goal).connected)
        return ok, (w_clear_path(g, s.start, s.goal) if ok else None)

    execution = None
    final = plan.final_scene
    connected, path = conn_and_path(final)
    success = bool(plan.success and path is not None)
    reason = plan.reason or ("planned" if success else "no W-clear path after the plan")
    write_result(plan=plan, final=final, path=path, connected=connected, success=success, reason=reason)
    if plan.success and plan.schedule and not args.no_execute:
        def replan(now):
            return plan_pushes(now, config.replace(time_limit_s=max(5.0, 0.5 * float(args.time_limit))),
                               mode_table=table)

        # One element at a time: the C engine unless MJX (JAX or Warp) is asked for by name.
        exec_backend = args.backend if args.backend in ("mjx", "warp") else "c"
        print(f"planned {len(plan.schedule)} pushes in {plan.stats.planning_time_s:.1f} s; executing in physics",
              file=sys.stderr)
        try:
            execution = execute_schedule(scene, plan, world=world, replan=replan,
                                         config=ExecutionConfig(max_replans=args.max_replans, backend=exec_backend))
        except KeyboardInterrupt:
            write_result(plan=plan, final=final, path=path, connected=connected, success=False,
                         reason="interrupted while executing")
            raise
        final, connected, path = execution.final_scene, execution.connectivity, execution.w_clear_path
        success = bool(execution.success)
        reason = (("executed; W-clear corridor open" if execution.executed else "Eq. 7 already holds; nothing to push")
                  if success else f"execution: {execution.reason}")
        write_result(plan=plan, execution=execution, final=final, path=path, connected=connected, success=success,
                     reason=reason)
        if table is not None:
            atomic_write(Path(args.mode_table), lambda fh: fh.write(json.dumps(table.to_dict(), indent=1).encode()))
    try:
        PushScene.from_dict(final.to_dict())
    except ValueError as exc:     # e.g. two bodies left interpenetrating by contact: say so, write it anyway
        final_check = f"the final scene does not pass validation: {exc}"
    else:
        final_check = "valid"
    kw = dict(plan=plan, execution=execution, final=final, path=path, connected=connected, success=success,
              reason=reason)
    write_result(**kw, final_check=final_check)
    try:
        run.write_json("scene_final.json", final.to_dict())
        title = (f"{'executed' if execution is not None else 'planned'}: "
                 f"{'W-clear corridor' if path is not None else 'no W-clear path'} (W = {scene.width:g} m)")
        run.write("pusharound.png", lambda fh: save_final_png(final, final.poses, final.robots, path, fh,
                                                               title=title))
        shown = execution if execution is not None else SimpleNamespace(
            frames=plan_frames(scene, plan), executed=plan.schedule, w_clear_path=path)
        with tqdm(total=1, desc="animation", unit="frame", file=sys.stderr, leave=False) as abar, \
                run.staged("pusharound.gif") as tmp:
            def tick(i, n):
                abar.total, abar.n = n, i
                abar.refresh()
            animate_execution(scene, shown, tmp, fps=args.fps, max_frames=args.max_frames, progress=tick)
    except OSError as exc:
        raise CLIError(f"--out: could not write into {str(run.path)!r} ({exc.strerror or exc}).") from None
    return plan, execution, success, path


def add_parsers(sub, fmt, scene_help: str) -> None:
    """Add this module's subcommands to the ``jaxplan`` parser's subparsers ``sub``."""
    p = sub.add_parser(
        "pusharound", formatter_class=fmt,
        help="PushAround: plan pushes that open a W-clear corridor, execute them in physics",
        description=wrap("Collaborative path clearing (PushAround): robots push movable obstacles "
                          "until a vehicle of width W can drive from start to goal. Plans a pushing "
                          "schedule with the physics-informed hybrid search (WCCG, gap ranking, "
                          "batched MuJoCo rollouts), executes it in physics (transitions, P-controlled "
                          "pushes, early stop, online replanning) and writes DIR/result.json "
                          "(success, W, start, goal, workspace, the schedule, the final polygon of "
                          "every obstacle, the W-clear path, planning and execution stats; written "
                          "also when planning fails), DIR/scene_final.json (the final scene, same "
                          "format as --scene), DIR/pusharound.png and DIR/pusharound.gif. Without "
                          "--scene the built-in nominal scene of --seed is used (8 x 5 m, two bars, "
                          "10-15 movables). See docs/pusharound.md."),
        epilog="examples:\n  jaxplan pusharound --out out/pusharound\n"
               "  jaxplan pusharound --seed 3 --time-limit 30 --out out/push3\n"
               "  jaxplan pusharound --scene my_scene.json --no-execute --out out/mine\n"
               "  jaxplan pusharound --mode-table modes.json --out out/pa   # reuse validated modes")
    p.add_argument("--scene", default=None, metavar="FILE.json",
                   help="a PushAround scene (JSON, docs/pusharound.md); default: the nominal scene of --seed")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    p.add_argument("--seed", type=SEED, default=0, metavar="N",
                   help="seed of the nominal scene and of the search's gap sampling, an int in [0, 2^32 - 1]; "
                        "default 0")
    p.add_argument("--backend", default="auto", choices=("auto", "c", "mjx", "warp"),
                   help="physics engine: c (MuJoCo C, fast on CPU), mjx (JAX, for GPUs) or auto "
                        "(mjx with a GPU, else c); default auto")
    p.add_argument("--time-limit", type=ranged(float, 0.0, MAX_TIME_LIMIT, lo_open=True, unit="s"), default=60.0,
                   metavar="S", help=f"planning time limit in seconds, in (0, {MAX_TIME_LIMIT:g}]; default 60")
    p.add_argument("--no-execute", action="store_true",
                   help="plan only: the outputs show the planned states (no physics execution)")
    p.add_argument("--mode-table", default=None, metavar="FILE",
                   help="ModeTable JSON: validated push modes are read from it (if it exists) and "
                        "saved back after planning")
    p.add_argument("--max-replans", type=ranged(int, 0, MAX_REPLANS, why="each replan searches again"), default=3,
                   metavar="N", help=f"online replans at most when a push fails in execution, an int in "
                                     f"[0, {MAX_REPLANS}]; default 3")
    p.add_argument("--fps", type=FPS, default=10, metavar="N",
                   help="animation frames per second, an int in [1, 50]; default 10")
    p.add_argument("--max-frames", type=ranged(int, 2, MAX_FRAMES), default=120, metavar="N",
                   help=f"animation frames at most (evenly subsampled), an int in [2, {MAX_FRAMES}]; default 120")
    p.set_defaults(func=_cmd_pusharound)
