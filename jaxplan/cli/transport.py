"""Subcommands of the environment-first transport system: ``fabric``, ``demo``, ``episode``, ``scenes``."""
from __future__ import annotations

import contextlib
import dataclasses
import math
import statistics
import sys
from pathlib import Path

import numpy as np

from jaxplan.cli.common import (
    FPS,
    MAP_SCENE_HELP,
    CLIError,
    add_site_seed_option,
    add_theta_option,
    check_fabric_memory,
    check_out_file,
    csv_text,
    fabric_params,
    load_scene,
    params_dict,
    ranged,
    run_folder,
    wrap,
)
from jaxplan.core import atomic_write, timed
from jaxplan.transport import BUILTIN_SCENES, DEFAULT_SCENE, K_MAX, MAX_PUSHES

FABRIC_ARRAYS = ("value", "length", "first_hop", "heading", "psi", "heat", "highways", "fallback",
                 "occupied", "table_raw", "table_len", "table_next_dir", "table_next_rank", "rounds",
                 "converged")


SUMMARY_KEYS = ("scene", "shape", "cell_size", "params", "total_mass", "occupied_cells",
                "max_value_J", "highway_cells", "roots_with_connector", "solver_iterations", "converged",
                "compile_ms", "warm_build_ms")


_WARM_REPEATS = 5


def _cmd_fabric(args) -> int:
    import jax

    from jaxplan.transport import build_fabric

    out = Path(args.out)
    if out.suffix.lower() != ".npz":
        raise CLIError(f"--out: the output file must end in '.npz'; got {args.out!r}.")
    check_out_file(args.out)
    params = fabric_params(args)
    scene = load_scene(args.scene, args.site_seed)
    check_fabric_memory(args, scene, params)
    fabric = jax.block_until_ready(build_fabric(scene, params))
    arrays = {
        "value": fabric.value, "length": fabric.length, "first_hop": fabric.first_hop,
        "heading": fabric.heading, "psi": fabric.psi, "heat": fabric.heat,
        "highways": fabric.highways, "fallback": fabric.fallback, "occupied": fabric.occupied,
        "table_raw": fabric.table.raw, "table_len": fabric.table.length,
        "table_next_dir": fabric.table.next_dir, "table_next_rank": fabric.table.next_rank,
        "rounds": fabric.rounds, "converged": fabric.converged,
        # context for readers of the file
        "target_mask": scene.target_mask, "cell_size": scene.cell_size, "origin": scene.origin,
        "theta_tol_deg": np.float32(params.theta_tol_deg), "tau_h": np.float32(params.tau_h),
        "k": np.int32(params.k), "monotone": np.bool_(params.monotone),
    }
    arrays = {key: np.asarray(value) for key, value in arrays.items()}
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(out, lambda fh: np.savez_compressed(fh, **arrays))
    except OSError as exc:
        raise CLIError(f"--out: could not write {str(out)!r} ({exc.strerror or exc}).") from None
    h, w = scene.shape
    print(f"fabric of {scene.name or args.scene} ({h}x{w}): J max {float(arrays['value'].max()):g}, "
          f"{int(arrays['highways'].sum())} highway cells, {int(arrays['rounds'])} solver iterations, "
          f"converged={bool(arrays['converged'])}")
    print(f"wrote {out}")
    return 0


def _cmd_demo(args) -> int:
    import matplotlib

    matplotlib.use("Agg")  # the demo only writes files; works without a display
    import jax
    import matplotlib.pyplot as plt
    from tqdm import tqdm

    from jaxplan.transport import build_fabric, plan_connectors, plot_fabric

    params, spill, ep = fabric_params(args), spill_params(args), episode_params(args)
    scene = load_scene(args.scene, args.site_seed)  # bad input fails here, before the progress bar starts
    check_fabric_memory(args, scene, params)
    with run_folder(args) as run:
        stages = ["build fabric (first call compiles)", "warm builds", "plan connectors", "plot"]
        with tqdm(total=len(stages), desc="jaxplan demo", unit="stage", file=sys.stderr,
                  leave=False) as bar:
            bar.set_postfix_str(stages[0])
            fabric, compile_ms = timed(build_fabric, scene, params)
            bar.update()
            bar.set_postfix_str(stages[1])
            warm = [timed(build_fabric, scene, params)[1] for _ in range(_WARM_REPEATS)]
            warm_ms = statistics.median(warm)
            bar.update()
            bar.set_postfix_str(stages[2])
            connectors = jax.block_until_ready(plan_connectors(scene, params, fabric))
            bar.update()
            bar.set_postfix_str(stages[3])
            fig = plot_fabric(scene, fabric, connectors)
            bar.update()

        h, w = scene.shape
        summary = {
            "scene": scene.name or args.scene,
            "shape": [h, w],
            "cell_size": float(np.asarray(scene.cell_size)),
            "params": params_dict(params),
            "total_mass": float(np.asarray(scene.total_mass)),
            "occupied_cells": int(np.asarray(fabric.occupied).sum()),
            "max_value_J": float(np.asarray(fabric.value).max()),
            "highway_cells": int(np.asarray(fabric.highways).sum()),
            "roots_with_connector": int(np.asarray(connectors.has_connector).sum()),
            "connectors_truncated": bool(np.asarray(connectors.truncated)),
            "solver_iterations": int(np.asarray(fabric.rounds)),
            "converged": bool(np.asarray(fabric.converged)),
            "compile_ms": round(compile_ms, 3),
            "warm_build_ms": round(warm_ms, 3),
            "timing_note": ("compile_ms: wall time of the first build_fabric call (trace + compile + "
                            "run; small if this process had compiled it already); warm_build_ms: "
                            f"median of {_WARM_REPEATS} further calls; both with "
                            "jax.block_until_ready."),
            "backend": jax.default_backend(),
            "jax_version": jax.__version__,
            "outputs": {"figure": str(run.file("fabric.png")), "summary": str(run.file("summary.json"))},
        }
        with _writing_into(run):
            try:
                run.write("fabric.png", lambda fh: fig.savefig(fh, format="png", dpi=120))
            finally:
                plt.close(fig)
            run.write_json("summary.json", summary)   # the fabric part lands even if the episode fails

        # the main job: an episode on the same scene (plan, push, spill, rebuild until delivered)
        episode = _run_episode(scene, params, spill, ep, record=not args.no_animation)
        summary["episode"] = _episode_summary(scene, args.scene, params, spill, ep, episode)
        with _writing_into(run):
            summary["outputs"].update(_episode_files(scene, episode, run, animate=not args.no_animation,
                                                     fps=args.fps))
            run.write_json("summary.json", summary)

    print(f"scene {summary['scene']!r}: {h}x{w}, cell size {summary['cell_size']:g}, "
          f"total mass {summary['total_mass']:g}, {summary['occupied_cells']} occupied cells")
    print(f"fabric (theta_tol {summary['params']['theta_tol_deg']:g} deg): max J "
          f"{summary['max_value_J']:g}, {summary['highway_cells']} highway cells, "
          f"{summary['roots_with_connector']} roots with a connector, {summary['solver_iterations']} solver "
          f"iterations, converged={summary['converged']}")
    print(f"build_fabric on {summary['backend']}: first call {compile_ms:.1f} ms (incl. compile), "
          f"warm {warm_ms:.2f} ms (median of {_WARM_REPEATS})")
    _print_episode(summary["episode"])
    for path in summary["outputs"].values():
        print(f"wrote {path}")
    return 0


_NO_CAPACITY = 1e9   # objects: the capacity-aware model without a binding cap (--mu alone)


def spill_dict(spill) -> dict:
    """The spill model of a summary.json: its type and every field (traced ones as floats, arrays as
    nested lists of floats; an infinite one, such as the default ``turn_saturation``, as the string
    "inf": JSON has no infinity)."""
    out = {"model": type(spill).__name__}
    for f in dataclasses.fields(spill):
        value = getattr(spill, f.name)
        if np.ndim(value) > 0:
            value = np.asarray(value, np.float64).tolist()
        elif not isinstance(value, (bool, int, str)):
            value = float(value)
            value = value if math.isfinite(value) else str(value)
        out[f.name] = value
    return out


_DEFAULT_LAM = 0.05
# --spill-model choices: the keys of jaxplan.transport.spillage.ROVER_MODELS, named here so that
# building the parser imports no JAX (tests/cli/test_rover.py holds the two equal)
SPILL_MODEL_NAMES = ("learned", "rover-fit")


def rover_spill_models() -> dict:
    """``jaxplan.transport.spillage.ROVER_MODELS``: the spill models fitted to the MuJoCo rover by
    ``--spill-model`` name."""
    from jaxplan.transport.spillage import ROVER_MODELS

    return ROVER_MODELS


DEFAULT_PUSHES = 200    # --max-pushes of a grid episode
PHYSICS_PUSHES = 15     # --max-pushes of an episode closed through physics (a few seconds of MuJoCo each)


_DEFAULT_SPILL_THRESHOLD = 1e-3


def _spill_options_given(args) -> bool:
    named = ("lam", "capacity", "mu", "miss", "turn_saturation")
    return (any(getattr(args, name, None) is not None for name in named)
            or getattr(args, "spill_threshold", _DEFAULT_SPILL_THRESHOLD) != _DEFAULT_SPILL_THRESHOLD)


def spill_params(args, default=None):
    """``SpillParams`` from the spill options; ``CapacitySpillParams`` when ``--capacity``, ``--mu``,
    ``--miss`` or ``--turn-saturation`` is given (its evaluator, ``capacity_spill``, follows from the
    type: ``jaxplan.transport.spillage.evaluator_for``). default: the model when no spill option is given (None:
    the curvature model with lam 0.05)."""
    from jaxplan.transport.spillage import SpillParams, validate_spill_params

    if default is not None and not _spill_options_given(args):
        return default
    lam = _DEFAULT_LAM if args.lam is None else args.lam
    capacity, mu = getattr(args, "capacity", None), getattr(args, "mu", None)
    miss, saturation = getattr(args, "miss", None), getattr(args, "turn_saturation", None)
    if capacity is None and mu is None and miss is None and saturation is None:
        spill = SpillParams(lam=lam, threshold=args.spill_threshold)
        validate_spill_params(spill)
        return spill
    from jaxplan.transport.spillage import CapacitySpillParams, validate_capacity_params

    spill = CapacitySpillParams(lam=lam, threshold=args.spill_threshold,
                                capacity=_NO_CAPACITY if capacity is None else capacity,
                                mu=0.0 if mu is None else mu, miss=0.0 if miss is None else miss,
                                turn_saturation=float("inf") if saturation is None else saturation)
    try:
        validate_capacity_params(spill)   # also rejects NaN and inf
    except ValueError as exc:
        field = str(exc).split(":")[0].rsplit(".", 1)[-1]   # "CapacitySpillParams.mu: ..." -> "mu"
        flag = {"capacity": "--capacity", "mu": "--mu", "miss": "--miss",
                "turn_saturation": "--turn-saturation"}.get(field)
        raise CLIError(f"{flag}: {exc}" if flag else str(exc)) from None
    return spill


def episode_params(args):
    from jaxplan.transport import EpisodeParams, validate_episode_params

    budget = args.max_pushes
    if budget is None:
        budget = PHYSICS_PUSHES if getattr(args, "physics", False) else DEFAULT_PUSHES
    ep = EpisodeParams(rearrange_margin=args.rearrange_margin, stop_fraction=args.stop_fraction,
                       max_pushes=budget, source_rule=args.source_rule, reselect=args.reselect,
                       rebuild=args.rebuild)
    validate_episode_params(ep)
    return ep


@contextlib.contextmanager
def _writing_into(run):
    """Turn a failed write into one ``--out`` error line."""
    try:
        yield
    except OSError as exc:
        raise CLIError(f"--out: could not write into {str(run.path)!r} ({exc.strerror or exc}).") from None


def _episode_files(scene, episode, run, *, animate: bool, fps: int) -> dict:
    """Write metrics (JSON, CSV), the final figure and the animation into ``run``; returns their paths.

    Files are written one by one, each atomically, cheapest first: if the animation fails the
    metrics and the figure are already on disk (and in the run's manifest).
    """
    import matplotlib.pyplot as plt
    from tqdm import tqdm

    from jaxplan.transport import animate_episode, plot_episode

    per_tick = episode.per_tick()
    paths = {"metrics_json": run.write_json("metrics.json", {"totals": episode.totals(), "per_tick": per_tick}),
             "metrics_csv": run.write("metrics.csv", lambda fh: fh.write(csv_text(per_tick).encode()))}
    fig = plot_episode(scene, episode)
    try:
        paths["episode_figure"] = run.write("episode.png", lambda fh: fig.savefig(fh, format="png", dpi=110))
    finally:
        plt.close(fig)
    if animate and episode.frames:
        with tqdm(total=len(episode.frames), desc="animation", unit="frame", file=sys.stderr, leave=False) as bar, \
                run.staged("episode.gif") as tmp:
            animate_episode(scene, episode, tmp, fps=fps, progress=lambda i, n: bar.update(1))
        paths["animation"] = run.file("episode.gif")
    return {k: str(v) for k, v in paths.items()}


def _run_episode(scene, params, spill, ep, *, record: bool):
    from jaxplan.transport import run_episode
    from jaxplan.transport.spillage import evaluator_for

    return run_episode(scene, params, spill, ep, record=record, progress=True, evaluator=evaluator_for(spill))


def _episode_summary(scene, spec, params, spill, ep, episode) -> dict:
    import jax

    totals = episode.totals()
    h, w = scene.shape
    return {
        "scene": scene.name or spec,
        "shape": [h, w],
        "initial_mass": totals["initial_mass"],
        "initial_remaining": totals["initial_remaining"],
        "unreachable_mass": float(np.asarray(scene.unreachable_mass)),   # cut off from every target: never pushed
        "delivered": totals["delivered"],
        "spilled": totals["spilled"],
        "remaining": totals["remaining"],
        "pushes": totals["pushes"],
        "rearrange_pushes": totals["rearrange_pushes"],
        "driven": totals["driven"],
        "stop_reason": episode.stop_reason,
        "message": episode.message,
        "median_plan_ms": totals["median_plan_ms"],
        "median_rebuild_ms": totals["median_rebuild_ms"],
        "params": params_dict(params),
        "spill": spill_dict(spill),
        "episode": {"rearrange_margin": float(ep.rearrange_margin), "stop_fraction": float(ep.stop_fraction),
                    "max_pushes": ep.max_pushes, "source_rule": ep.source_rule, "reselect": ep.reselect,
                    "rebuild": ep.rebuild},
        "rebuild": totals["rebuild"],
        "notes": ("masses in objects; delivered/spilled/remaining are the final cumulative values; "
                  "spilled mass stays on the grid and may be pushed again; the first tick's "
                  "plan/rebuild times include compilation (medians are robust to it)"),
        "backend": jax.default_backend(),
    }


def _print_episode(summary: dict) -> None:
    print(f"episode: {summary['pushes']} pushes ({summary['rearrange_pushes']} via highway), stop: "
          f"{summary['stop_reason']} - {summary['message']}")
    print(f"mass: initial {summary['initial_mass']:g}, delivered {summary['delivered']:.2f}, "
          f"spilled (cumulative) {summary['spilled']:.2f}, remaining {summary['remaining']:.2f}")
    if summary["median_plan_ms"] is not None:
        print(f"per tick (median): plan {summary['median_plan_ms']:.2f} ms, {summary['rebuild']} rebuild "
              f"{summary['median_rebuild_ms']:.2f} ms")


def _cmd_episode(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    if args.physics:
        return _cmd_closed_loop(args)
    params, spill, ep = fabric_params(args), spill_params(args), episode_params(args)
    scene = load_scene(args.scene, args.site_seed)
    check_fabric_memory(args, scene, params)
    with run_folder(args) as run:
        episode = _run_episode(scene, params, spill, ep, record=not args.no_animation)
        summary = _episode_summary(scene, args.scene, params, spill, ep, episode)
        with _writing_into(run):
            summary["outputs"] = _episode_files(scene, episode, run, animate=not args.no_animation, fps=args.fps)
            summary["outputs"]["summary"] = str(run.file("summary.json"))
            run.write_json("summary.json", summary)
    _print_episode(summary)
    for _name, path in summary["outputs"].items():
        print(f"wrote {path}")
    return 0


def _cmd_closed_loop(args) -> int:
    """``jaxplan episode --physics``: the episode closed through MuJoCo (``physics.closed_loop``)."""
    import matplotlib.pyplot as plt

    from jaxplan.transport.physics import (
        animate_closed_loop,
        grid_episode,
        plot_closed_loop,
        run_closed_loop,
    )

    params, ep = fabric_params(args), episode_params(args)
    spill = spill_params(args, default=rover_spill_models()["learned"])   # the rover's own fit unless asked otherwise
    scene = load_scene(args.scene, args.site_seed)
    check_fabric_memory(args, scene, params)
    with run_folder(args) as run:
        loop = run_closed_loop(scene, params, spill, ep, max_pushes=max(ep.max_pushes, 1), progress=True)
        grid_only = grid_episode(scene, params, spill, ep, max_pushes=max(ep.max_pushes, 1))
        summary = closed_loop_summary(args.scene, spill, loop, grid_only)
        with _writing_into(run):
            fig = plot_closed_loop(loop, grid_only, title=f"{scene.name or args.scene}: physics against the plan")
            fig.savefig(run.file("closed_loop.png"), dpi=110)
            plt.close(fig)
            outputs = {"figure": str(run.file("closed_loop.png"))}
            if not args.no_animation:
                animate_closed_loop(scene, loop, run.file("closed_loop.gif"), fps=args.fps)
                outputs["animation"] = str(run.file("closed_loop.gif"))
            np.savez_compressed(run.file("counts.npz"), obj=loop.obj.astype(np.float32))
            outputs["counts"] = str(run.file("counts.npz"))
            outputs["summary"] = str(run.file("summary.json"))
            summary["outputs"] = outputs
            run.write_json("summary.json", summary)
    final = summary["final"]
    print(f"{len(loop.pushes)} pushes in physics ({loop.stop_reason}): delivered {final['delivered']:.1f}, "
          f"predicted push by push {final['predicted']:.1f}, grid-only episode {final['grid_only']:.1f}; "
          f"cumulative prediction within 10% after {summary['within_10pct_after']} of {len(loop.pushes)} pushes")
    for path in outputs.values():
        print(f"wrote {path}")
    return 0


def closed_loop_summary(scene_name, spill, loop, grid_only) -> dict:
    """summary.json of ``jaxplan episode --physics``: every push, both cumulative curves, and after
    how many pushes the cumulative prediction lies within 10% of physics."""
    within = loop.relative_error <= 0.1
    return {"scene": scene_name, "spill": spill_dict(spill), "stop_reason": loop.stop_reason,
            "pushes": loop.pushes, "cumulative": {"physics": loop.delivered.tolist(),
                                                  "predicted": loop.predicted.tolist(),
                                                  "grid_only": np.asarray(grid_only).tolist()},
            "within_10pct_after": int(within.sum()), "within_10pct_every_push": bool(within.all()),
            "final": {"delivered": float(loop.delivered[-1]), "predicted": float(loop.predicted[-1]),
                      "grid_only": float(np.asarray(grid_only)[-1]),
                      "spilled": float(sum(p["spilled"] for p in loop.pushes)),
                      "left_behind": float(sum(p["left_behind"] for p in loop.pushes)),
                      "lost": float(sum(p["lost"] for p in loop.pushes))},
            "notes": "masses in objects; physics = the target cells' gain on the grid rasterised from the "
                     "particles; predicted = the grid's push of the same route from the same counts"}


def _cmd_scenes(args) -> int:
    from jaxplan.transport import builtin_scene

    rows = []
    for name in BUILTIN_SCENES:
        scene = builtin_scene(name)
        h, w = scene.shape
        rows.append((name + (" (default)" if name == DEFAULT_SCENE else ""), f"{h}x{w}",
                     type(scene.target).__name__, str(int(np.asarray(scene.occupied).sum())),
                     f"{float(np.asarray(scene.total_mass)):g}"))
    header = ("name", "shape", "target", "occupied", "mass")
    widths = [max(len(r[i]) for r in rows + [header]) for i in range(len(header))]
    for row in [header] + rows:
        print("  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip())
    return 0


def add_spill_options(p) -> None:
    p.add_argument("--lam", type=ranged(float, 0.0), default=None, metavar="X",
                   help="spill model lambda: fraction of the load spilled per radian of turning, >= 0; "
                        "default 0.05 (0 = no spillage)")
    p.add_argument("--spill-threshold", type=ranged(float, 0.0), default=_DEFAULT_SPILL_THRESHOLD, metavar="OBJ",
                   help="per-sample spills below this many objects are ignored, >= 0; default 0.001")
    p.add_argument("--capacity", type=ranged(float, 0.0, lo_open=True), default=None, metavar="OBJ",
                   help="use the capacity-aware spill model (jaxplan.transport.spillage.capacity): the blade carries "
                        "at most this many objects, > 0; default: the curvature model (no capacity)")
    p.add_argument("--mu", type=ranged(float, 0.0), default=None, metavar="X",
                   help="capacity-aware model: fraction of the load lost per world unit driven, >= 0 "
                        "(implies the capacity-aware model, uncapped unless --capacity is given); "
                        "experiments/bench_rover.py fits lam, mu and capacity to the rover's physics")
    p.add_argument("--miss", type=ranged(float, 0.0), default=None, metavar="X",
                   help="capacity-aware model: fraction of a cell's objects the blade leaves behind per radian "
                        "of turning at that cell, >= 0 (implies the capacity-aware model); default 0")
    p.add_argument("--turn-saturation", type=ranged(float, 0.0, lo_open=True, inf_ok=True), default=None,
                   metavar="OBJ",
                   help="capacity-aware model: load at which the turning spill is half of lam x load per radian, "
                        "> 0 (implies the capacity-aware model); default: none (proportional to the load)")


def _add_episode_options(p) -> None:
    add_spill_options(p)
    p.add_argument("--max-pushes", type=ranged(int, 0, MAX_PUSHES, why="the tick counter is an int32 in the "
                                                                     "compiled step; 10^6 pushes take hours"),
                   default=None, metavar="N",
                   help=f"push budget, an int in [0, {MAX_PUSHES}]; default {DEFAULT_PUSHES} "
                        f"({PHYSICS_PUSHES} with episode --physics)")
    p.add_argument("--rearrange-margin", type=ranged(float, 0.0, inf_ok=True), default=0.1, metavar="X",
                   help="choose Rearrange (connector + highway) when it collects more than (1 + X) "
                        "times the direct route; >= 0, 'inf' never rearranges; default 0.1")
    p.add_argument("--stop-fraction", type=ranged(float, 0.0, 1.0, hi_open=True), default=0.02, metavar="X",
                   help="stop when the mass outside the target is at most X of its initial value, "
                        "in [0, 1); default 0.02")
    p.add_argument("--source-rule", default="max_value", choices=("max_value", "nearest"),
                   help="which occupied cell to push from: the one whose route collects most "
                        "(max_value, default) or the one nearest the target")
    p.add_argument("--reselect", action="store_true",
                   help="before each push, choose every source's route by delivered mass (Eq. 6) and let "
                        "headings, psi, the heatmap and highways follow those routes, as the paper does "
                        "(default: they follow the raw-count optimum, Eq. 5; the pushed route is the Eq. 6 "
                        "choice either way). Costs a spill evaluation of every source's candidate routes per tick")
    p.add_argument("--rebuild", default="auto", choices=("auto", "selective", "full"),
                   help="how the fabric is refreshed after each push; all give the same fabric: selective "
                        "(recompute only the cells a push can change), full (build from scratch), or auto "
                        "(default: full on a GPU and on CPU grids under 2,500 cells, where it is as fast or "
                        "faster; selective otherwise)")
    p.add_argument("--fps", type=FPS, default=4, metavar="N",
                   help="animation frames per second, an int in [1, 50]; default 4")
    p.add_argument("--no-animation", action="store_true", help="skip the GIF (faster)")


def add_parsers(sub, fmt, scene_help: str) -> None:
    """Add this module's subcommands to the ``jaxplan`` parser's subparsers ``sub``."""
    p = sub.add_parser(
        "fabric", formatter_class=fmt, help="build the fabric of a scene and save its arrays (.npz)",
        description=wrap("Load a scene, build its fabric with build_fabric and write the arrays "
                          "to a compressed .npz: " + ", ".join(FABRIC_ARRAYS) + " (table_* are "
                          "the K-best continuation table, [H, W, K]), plus target_mask, "
                          "cell_size, origin and the parameters. The file is written atomically "
                          "(temp file + rename)."),
        epilog="example:\n  jaxplan fabric --scene default --theta-tol 45 --out out/fabric.npz\n"
               "  python -c \"import numpy as np; print(np.load('out/fabric.npz')['value'].max())\"\n"
               "  jaxplan fabric --scene tests/data/small.map --site-seed 3 --out out/small_map.npz")
    p.add_argument("--scene", required=True, metavar="FILE_OR_NAME", help=scene_help + MAP_SCENE_HELP)
    add_site_seed_option(p)
    add_theta_option(p)
    p.add_argument("--tau-h", type=ranged(float, 0.0, 1.0, why="a fraction of the largest heat value"), default=0.5,
                   metavar="X", help="highway threshold (Eq. 11), a fraction of max heat in [0, 1]; default 0.5")
    p.add_argument("--k", type=ranged(int, 1, K_MAX, why="the K-best merge is compiled unrolled; its compile "
                                                         "memory grows about as K^5, about 7 GB at K = 16"),
                   default=4, metavar="K",
                   help=f"depth of the continuation table (K best paths per cell), an int in [1, {K_MAX}]; "
                        "refused when its estimated build memory (estimate_build_bytes: about 0.3 GB at 8, "
                        "1.8 GB at 12, 7 GB at 16) exceeds the memory available; default 4")
    p.add_argument("--no-monotone", action="store_true",
                   help="drop the strict monotone rule (hop-capped DP; see docs/transport.md)")
    p.add_argument("--out", required=True, metavar="OUT.npz", help="output file (.npz)")
    p.set_defaults(func=_cmd_fabric)

    p = sub.add_parser(
        "demo", formatter_class=fmt,
        help="the main job on a scene: fabric figure, then a whole episode (push until delivered)",
        description=wrap("Build the fabric and the highway connectors of a scene (default: the "
                          f"built-in {DEFAULT_SCENE!r} scene) and write DIR/fabric.png "
                          "(heatmap, first-hop headings, connector headings, highways); then run an "
                          "episode on it, as 'jaxplan episode' does, writing DIR/episode.png, "
                          "DIR/episode.gif, DIR/metrics.json and DIR/metrics.csv. DIR/summary.json "
                          "holds the fabric's sizes, totals and build times and, under 'episode', "
                          "the initial mass and the final delivered, spilled and remaining mass. "
                          "The first calls compile, which takes some seconds."),
        epilog="example:\n  jaxplan demo --scene corridor --theta-tol 45 --out out/corridor\n"
               "  jaxplan demo --scene tests/data/small.map --site-seed 3 --out out/small_map")
    p.add_argument("--scene", default=DEFAULT_SCENE, metavar="NAME_OR_FILE",
                   help=scene_help + MAP_SCENE_HELP + f"; default {DEFAULT_SCENE!r}")
    add_site_seed_option(p)
    p.add_argument("--out", default="out/demo", metavar="DIR",
                   help="output directory (created if missing); default out/demo")
    add_theta_option(p)
    _add_episode_options(p)
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser(
        "episode", formatter_class=fmt,
        help="run a whole transport job on a scene: plan, push, spill, rebuild until delivered",
        description=wrap("Run an episode (docs/transport.md, 'Episodes'): each tick picks a "
                          "source, chooses Deliver (its best route to the target under the spill "
                          "model) or Rearrange (a connector to a highway, then the highway), pushes "
                          "it on the grid (collect, spill beside the path, deposit in the target) and "
                          "rebuilds the fabric (--rebuild), until the mass outside the target falls "
                          "under --stop-fraction or --max-pushes is spent. Writes DIR/summary.json "
                          "(initial mass; final delivered, spilled, remaining), DIR/metrics.json and "
                          "DIR/metrics.csv (per tick: delivered, spilled, remaining, pushes, mode, "
                          "distance driven, plan and rebuild times), DIR/episode.png and "
                          "DIR/episode.gif (heatmap, headings, highways, connector and pushed route, "
                          "tick by tick)."),
        epilog="example:\n  jaxplan episode --scene default --out out/episode\n"
               "  jaxplan episode --scene my_site.json --lam 0.1 --max-pushes 50 --out out/site\n"
               "  jaxplan episode --scene tests/data/small.map --site-seed 3 --out out/small_map\n"
               "  jaxplan episode --scene default --physics --max-pushes 5 --out out/physics_episode")
    p.add_argument("--scene", required=True, metavar="FILE_OR_NAME", help=scene_help + MAP_SCENE_HELP)
    add_site_seed_option(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    add_theta_option(p)
    _add_episode_options(p)
    p.add_argument("--physics", action="store_true",
                   help="close the episode through physics: push each planned route with the MuJoCo rover "
                        "(C engine), rasterise the particles back to counts and plan the next push from "
                        "them; writes DIR/summary.json (per push: physics' delivered mass against the "
                        "grid's prediction from the same counts; both cumulative curves and a grid-only "
                        "episode's), DIR/closed_loop.png, DIR/closed_loop.gif and DIR/counts.npz. Predicts "
                        "with the rover's learned spill model (LEARNED_FIT) unless a spill option is given")
    p.set_defaults(func=_cmd_episode)

    p = sub.add_parser(
        "scenes", formatter_class=fmt, help="list the built-in scenes",
        description=wrap("List the built-in scenes with their grid shape, target type, number "
                          "of occupied cells and total mass. Use a name with --scene."),
        epilog="example:\n  jaxplan scenes\n  jaxplan demo --scene two_targets")
    p.set_defaults(func=_cmd_scenes)
