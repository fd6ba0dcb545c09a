"""The ``jaxplan`` command line: ``fabric``, ``demo``, ``episode``, ``teams``, ``rover``, ``pusharound``,
``sweep`` and ``scenes``.

Every subcommand has ``--help`` with an example. Bad input (a missing scene file, an unknown built-in
name, an out-of-range parameter) prints one ``error: ...`` line to stderr and exits with code 2.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import statistics
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

from jaxplan.scene import BUILTIN_SCENES, DEFAULT_SCENE

__all__ = ["main"]

EXIT_BAD_INPUT = 2

FABRIC_ARRAYS = ("value", "length", "first_hop", "heading", "psi", "heat", "highways", "fallback",
                 "occupied", "table_raw", "table_len", "table_next_dir", "table_next_rank", "rounds",
                 "converged")
SUMMARY_KEYS = ("scene", "shape", "cell_size", "params", "total_mass", "occupied_cells",
                "max_value_J", "highway_cells", "roots_with_connector", "solver_iterations", "converged",
                "compile_ms", "warm_build_ms")

_WARM_REPEATS = 5


class CLIError(Exception):
    """Bad command-line input; the message is printed as ``error: <message>``."""


# --------------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------------

def _load_scene(spec: str):
    """A built-in scene by name, or a scene file (.npz / .json) by path."""
    from jaxplan.scene import Scene, builtin_scene

    if spec in BUILTIN_SCENES:
        return builtin_scene(spec)
    path = Path(spec)
    if path.is_file():
        try:
            return Scene.load(path)
        except OSError as exc:
            raise CLIError(f"--scene: could not read {spec!r} ({exc.strerror or exc}).") from None
    if path.suffix.lower() in (".npz", ".json") or os.sep in spec or path.exists():
        raise CLIError(f"--scene: no such scene file {spec!r}.")
    raise CLIError(f"--scene: {spec!r} is neither a built-in scene ({', '.join(BUILTIN_SCENES)}) "
                   "nor an existing .npz/.json scene file.")


def _params(args):
    from jaxplan.params import FabricParams, validate_params

    params = FabricParams(theta_tol_deg=args.theta_tol, tau_h=getattr(args, "tau_h", 0.5),
                          k=getattr(args, "k", 4), monotone=not getattr(args, "no_monotone", False))
    validate_params(params)  # before any expensive work; raises ValueError naming the field
    return params


def _params_dict(params) -> dict:
    out = {}
    for key in ("theta_tol_deg", "tau_h", "anchor_lambda", "slack_tau", "monotone", "k",
                "max_hops", "highway_relative", "highway_smoothing", "highway_nms"):
        value = getattr(params, key)
        if isinstance(value, (bool, np.bool_)) or value is None:
            out[key] = None if value is None else bool(value)
        elif isinstance(value, (int, np.integer)):
            out[key] = int(value)
        else:
            out[key] = float(np.asarray(value))
    return out


def _atomic_write(path: Path, write) -> None:
    """Call ``write(binary_file)`` on a temp file next to ``path``, then rename it into place.

    Nothing is left at ``path`` (or beside it) when ``write`` fails. The file gets the usual
    permissions (0666 minus the umask), not mkstemp's 0600.
    """
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _timed(fn, *args):
    """``(result, milliseconds)`` of one call, waiting for every output array."""
    from jaxplan._timing import timed

    return timed(fn, *args)


# --------------------------------------------------------------------------------------------------
# Subcommands
# --------------------------------------------------------------------------------------------------

def _cmd_fabric(args) -> int:
    import jax

    from jaxplan.fabric import build_fabric

    out = Path(args.out)
    if out.suffix.lower() != ".npz":
        raise CLIError(f"--out: the output file must end in '.npz'; got {args.out!r}.")
    params = _params(args)
    scene = _load_scene(args.scene)
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
        _atomic_write(out, lambda fh: np.savez_compressed(fh, **arrays))
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

    from jaxplan.connectors import plan_connectors
    from jaxplan.fabric import build_fabric
    from jaxplan.viz import plot_fabric

    params, spill, ep = _params(args), _spill_params(args), _episode_params(args)
    scene = _load_scene(args.scene)  # bad input fails here, before the progress bar starts
    out_dir = Path(args.out)
    stages = ["build fabric (first call compiles)", "warm builds", "plan connectors", "plot"]
    with tqdm(total=len(stages), desc="jaxplan demo", unit="stage", file=sys.stderr,
              leave=False) as bar:
        bar.set_postfix_str(stages[0])
        fabric, compile_ms = _timed(build_fabric, scene, params)
        bar.update()
        bar.set_postfix_str(stages[1])
        warm = [_timed(build_fabric, scene, params)[1] for _ in range(_WARM_REPEATS)]
        warm_ms = statistics.median(warm)
        bar.update()
        bar.set_postfix_str(stages[2])
        connectors = jax.block_until_ready(plan_connectors(scene, params, fabric))
        bar.update()
        bar.set_postfix_str(stages[3])
        fig = plot_fabric(scene, fabric, connectors)
        bar.update()

    png = out_dir / "fabric.png"
    summary_path = out_dir / "summary.json"
    h, w = scene.shape
    summary = {
        "scene": scene.name or args.scene,
        "shape": [h, w],
        "cell_size": float(np.asarray(scene.cell_size)),
        "params": _params_dict(params),
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
        "outputs": {"figure": str(png), "summary": str(summary_path)},
    }
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        _atomic_write(png, lambda fh: fig.savefig(fh, format="png", dpi=120))
        _write_json(summary_path, summary)   # the fabric part lands even if the episode fails
    except OSError as exc:
        raise CLIError(f"--out: could not write into {str(out_dir)!r} "
                       f"({exc.strerror or exc}).") from None
    finally:
        plt.close(fig)

    # the main job: an episode on the same scene (plan, push, spill, rebuild until delivered)
    episode = _run_episode(scene, params, spill, ep, record=not args.no_animation)
    summary["episode"] = _episode_summary(scene, args.scene, params, spill, ep, episode)
    try:
        summary["outputs"].update(_episode_files(scene, episode, out_dir, animate=not args.no_animation,
                                                 fps=args.fps))
        _write_json(summary_path, summary)
    except OSError as exc:
        raise CLIError(f"--out: could not write into {str(out_dir)!r} "
                       f"({exc.strerror or exc}).") from None

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


def _spill_dict(spill) -> dict:
    """The spill model of a summary.json: its type and every field (traced ones as floats; an infinite
    one, such as the default ``turn_saturation``, as the string "inf": JSON has no infinity)."""
    out = {"model": type(spill).__name__}
    for f in dataclasses.fields(spill):
        value = getattr(spill, f.name)
        if not isinstance(value, (bool, int, str)):
            value = float(value)
            value = value if math.isfinite(value) else str(value)
        out[f.name] = value
    return out


_DEFAULT_LAM = 0.05
_DEFAULT_SPILL_THRESHOLD = 1e-3


def _spill_options_given(args) -> bool:
    named = ("lam", "capacity", "mu", "miss", "turn_saturation")
    return (any(getattr(args, name, None) is not None for name in named)
            or getattr(args, "spill_threshold", _DEFAULT_SPILL_THRESHOLD) != _DEFAULT_SPILL_THRESHOLD)


def _spill_params(args, default=None):
    """``SpillParams`` from the spill options; ``CapacitySpillParams`` when ``--capacity``, ``--mu``,
    ``--miss`` or ``--turn-saturation`` is given (its evaluator, ``capacity_spill``, follows from the
    type: ``spill_capacity.evaluator_for``). default: the model when no spill option is given (None:
    the curvature model with lam 0.05)."""
    from jaxplan.spillage import SpillParams, validate_spill_params

    if default is not None and not _spill_options_given(args):
        return default
    lam = _DEFAULT_LAM if args.lam is None else args.lam
    capacity, mu = getattr(args, "capacity", None), getattr(args, "mu", None)
    miss, saturation = getattr(args, "miss", None), getattr(args, "turn_saturation", None)
    if capacity is None and mu is None and miss is None and saturation is None:
        spill = SpillParams(lam=lam, threshold=args.spill_threshold)
        validate_spill_params(spill)
        return spill
    from jaxplan.spill_capacity import CapacitySpillParams, validate_capacity_params

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


def _episode_params(args):
    from jaxplan.episode import EpisodeParams, validate_episode_params

    ep = EpisodeParams(rearrange_margin=args.rearrange_margin, stop_fraction=args.stop_fraction,
                       max_pushes=args.max_pushes, source_rule=args.source_rule, reselect=args.reselect,
                       rebuild=args.rebuild)
    validate_episode_params(ep)
    return ep


def _write_json(path: Path, data) -> None:
    text = json.dumps(data, indent=2) + "\n"
    _atomic_write(path, lambda fh: fh.write(text.encode()))


def _write_csv(path: Path, columns: dict) -> None:
    names = list(columns)
    lines = [",".join(names)] + [",".join(str(v) for v in row) for row in zip(*columns.values())]
    _atomic_write(path, lambda fh: fh.write(("\n".join(lines) + "\n").encode()))


def _episode_files(scene, episode, out_dir: Path, *, animate: bool, fps: int) -> dict:
    """Write metrics (JSON, CSV), the final figure and the animation; returns their paths.

    Files are written one by one, each atomically, cheapest first: if the animation fails the
    metrics and the figure are already on disk.
    """
    import matplotlib.pyplot as plt
    from tqdm import tqdm

    from jaxplan.viz import animate_episode, plot_episode

    paths = {"metrics_json": out_dir / "metrics.json", "metrics_csv": out_dir / "metrics.csv",
             "episode_figure": out_dir / "episode.png"}
    _write_json(paths["metrics_json"], {"totals": episode.totals(), "per_tick": episode.per_tick()})
    _write_csv(paths["metrics_csv"], episode.per_tick())
    fig = plot_episode(scene, episode)
    try:
        _atomic_write(paths["episode_figure"], lambda fh: fig.savefig(fh, format="png", dpi=110))
    finally:
        plt.close(fig)
    if animate and episode.frames:
        paths["animation"] = out_dir / "episode.gif"
        tmp = out_dir / ".episode.gif.tmp.gif"
        with tqdm(total=len(episode.frames), desc="animation", unit="frame", file=sys.stderr, leave=False) as bar:
            try:
                animate_episode(scene, episode, tmp, fps=fps, progress=lambda i, n: bar.update(1))
                os.replace(tmp, paths["animation"])
            finally:
                if tmp.exists():
                    tmp.unlink()
    return {k: str(v) for k, v in paths.items()}


def _run_episode(scene, params, spill, ep, *, record: bool):
    from jaxplan.episode import run_episode
    from jaxplan.spill_capacity import evaluator_for

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
        "params": _params_dict(params),
        "spill": _spill_dict(spill),
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
    params, spill, ep = _params(args), _spill_params(args), _episode_params(args)
    scene = _load_scene(args.scene)
    out_dir = Path(args.out)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CLIError(f"--out: could not create {str(out_dir)!r} ({exc.strerror or exc}).") from None
    episode = _run_episode(scene, params, spill, ep, record=not args.no_animation)
    summary = _episode_summary(scene, args.scene, params, spill, ep, episode)
    try:
        summary["outputs"] = _episode_files(scene, episode, out_dir, animate=not args.no_animation, fps=args.fps)
        summary["outputs"]["summary"] = str(out_dir / "summary.json")
        _write_json(out_dir / "summary.json", summary)
    except OSError as exc:
        raise CLIError(f"--out: could not write into {str(out_dir)!r} ({exc.strerror or exc}).") from None
    _print_episode(summary)
    for name, path in summary["outputs"].items():
        print(f"wrote {path}")
    return 0


def _cmd_teams(args) -> int:
    import matplotlib

    matplotlib.use("Agg")  # writes files only; works without a display
    from jaxplan.teams.report import run_paper

    summary = run_paper(args.out, strategy=args.strategy, seed=args.seed, v_after=args.v_after,
                        deadline=args.deadline, steps=args.steps, write=_atomic_write)
    for team in summary["teams"]:
        print(f"team {team['team']}: cleared at {team['clear_time_s']} s, delivered "
              f"{team['delivered_kg']:g} of {team['initial_mass_kg']:g} kg (last at "
              f"{team['finishing_time_s']} s), up to {team['max_trucks']} trucks")
    print(f"deadline {summary['deadline_s']:g} s met: {summary['deadline_met']}; "
          f"peak {summary['peak_trucks']} trucks")
    print(f"wrote {summary['outputs']['figure']}")
    print(f"wrote {summary['outputs']['summary']}")
    return 0


def _cmd_rover(args) -> int:
    # offscreen rendering needs the EGL backend chosen before mujoco is first imported
    os.environ.setdefault("MUJOCO_GL", "egl")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from tqdm import tqdm

    if args.routes < 1:
        raise CLIError(f"--routes: must be an int >= 1; got {args.routes}.")
    if not args.speed > 0:
        raise CLIError(f"--speed: must be > 0 cells/s; got {args.speed}.")
    if args.friction is not None and not (math.isfinite(args.friction) and args.friction > 0):
        raise CLIError(f"--friction: must be a positive number; got {args.friction}.")
    from jaxplan.spill_capacity import ROVER_FIT

    # the prediction the physics is compared with: the model fitted to this rover unless asked otherwise
    spill = _spill_params(args, default=ROVER_FIT)
    params = _params(args)
    scene = _load_scene(args.scene)
    out_dir = Path(args.out)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CLIError(f"--out: could not create {str(out_dir)!r} ({exc.strerror or exc}).") from None

    from jaxplan.physics import bridge, report
    from jaxplan.physics.rover import RoverConfig

    stages = ["plan (build_fabric + extract_paths)", "physics rollouts", "figure", "rendering"]
    with tqdm(total=len(stages), desc="jaxplan rover", unit="stage", file=sys.stderr, leave=False) as bar:
        bar.set_postfix_str(stages[0])
        _, routes, sources = bridge.plan_routes(scene, params, args.routes)
        bar.update()
        bar.set_postfix_str(stages[1])
        start = time.perf_counter()
        check = bridge.check_routes(scene, routes, config=RoverConfig(solver=args.solver), spill=spill,
                                    speed=args.speed, backend=args.backend, friction=args.friction)
        rollout_s = time.perf_counter() - start
        bar.update()
        bar.set_postfix_str(stages[2])
        rows = check.outcome.rows()
        fig = report.plot_check(scene, check, route=0)
        bar.update()
        bar.set_postfix_str(stages[3])
        frames_note = None
        frames = None
        if args.no_render:
            frames_note = "skipped (--no-render)"
        else:
            try:
                frames = report.render_frames(check, route=0)
            except Exception as exc:  # any GL failure: report it, keep the other outputs
                frames_note = f"rendering unavailable ({type(exc).__name__}: {exc})"
        bar.update()

    paths = {"table": out_dir / "routes.md", "figure": out_dir / "rover.png", "summary": out_dir / "summary.json"}
    b = len(rows)
    summary = {
        "scene": scene.name or args.scene,
        "shape": list(scene.shape),
        "backend": check.trajectory.backend,
        "routes": [dict(row, source=[int(v) for v in sources[i]]) for i, row in enumerate(rows)],
        "n_particles": check.world.n_particles,
        "contact_caps": check.world.caps,
        "ticks": check.n_ticks,
        "tick_seconds": check.world.config.timestep * check.world.config.substeps,
        "rollout_seconds": round(rollout_s, 3),
        "throughput_route_steps_per_s": round(b * check.n_ticks * check.world.config.substeps / rollout_s, 1),
        "speed_cells_per_s": args.speed,
        "friction": check.world.config.friction if args.friction is None else args.friction,
        "solver": check.world.config.solver,
        "spill": _spill_dict(spill),
        "spill_preset": "ROVER_FIT" if spill is ROVER_FIT else None,
        "notes": ("masses in objects (1 particle = 1 object); predicted_* from the 2D push "
                  "(execute.execute); lateral errors in cells, blade point to spline; rollout_seconds "
                  "includes compilation on MJX"),
    }
    try:
        _atomic_write(paths["figure"], lambda fh: fig.savefig(fh, format="png", dpi=110))
        _atomic_write(paths["table"], lambda fh: fh.write(report.table_markdown(rows).encode()))
        if frames is not None:
            paths["frames"] = out_dir / "frames.png"
            strip = np.concatenate(list(frames), axis=1)
            _atomic_write(paths["frames"], lambda fh: plt.imsave(fh, strip, format="png"))
        summary["frames"] = frames_note or f"{len(frames)} frames of route 0 in {paths['frames']}"
        summary["outputs"] = {k: str(v) for k, v in paths.items()}
        _write_json(paths["summary"], summary)
    except OSError as exc:
        raise CLIError(f"--out: could not write into {str(out_dir)!r} ({exc.strerror or exc}).") from None
    finally:
        plt.close(fig)
    print(report.table_markdown(rows), end="")
    print(f"{b} routes x {check.n_ticks} ticks on the {summary['backend']} engine in {rollout_s:.1f} s; "
          f"frames: {summary['frames']}")
    for path in summary["outputs"].values():
        print(f"wrote {path}")
    return 0


# --------------------------------------------------------------------------------------------------
# pusharound (docs/pusharound.md, "Execution and CLI")
# --------------------------------------------------------------------------------------------------

PUSHAROUND_RESULT_FORMAT = "jaxplan.pusharound.result"


def _pusharound_scene(args):
    """The scene of ``--scene`` (a JSON file) or the built-in ``nominal_scene(--seed)``."""
    from jaxplan.pusharound import PushScene, nominal_scene

    if args.scene is None:
        return nominal_scene(args.seed), f"nominal_scene(seed={args.seed})"
    path = Path(args.scene)
    if not path.is_file():
        raise CLIError(f"--scene: no such scene file {args.scene!r} (a PushAround scene .json, see "
                       "docs/pusharound.md; leave --scene out for the built-in nominal scene).")
    try:
        return PushScene.load(path), str(path)
    except OSError as exc:
        raise CLIError(f"--scene: could not read {args.scene!r} ({exc.strerror or exc}).") from None
    except UnicodeDecodeError:
        raise CLIError(f"--scene: {args.scene!r} is not a text (JSON) file.") from None
    except ValueError as exc:
        msg = str(exc)
        raise CLIError(f"--scene: {msg}" if msg.startswith(str(path)) else f"--scene: {args.scene}: {msg}") from None
    except (KeyError, TypeError, IndexError, AttributeError) as exc:  # a malformed entry the parser did not name
        raise CLIError(f"--scene: {args.scene}: malformed scene ({type(exc).__name__}: {exc}); "
                       "see docs/pusharound.md for the format.") from None


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
            "target_before": _xy(np.asarray(item.poses_before)[m]), "target_after": _xy(np.asarray(item.poses_after)[m]),
            "poses_before": _xy(item.poses_before), "poses_after": _xy(item.poses_after),
            "robots_before": _xy(item.robots_before), "robots_after": _xy(item.robots_after)}


def _obstacle_records(scene) -> list:
    """Every movable (at its pose) and fixed obstacle: world outline (exterior + holes) and convex pieces."""
    def rings(poly):
        parts = list(getattr(poly, "geoms", [poly]))
        main = max(parts, key=lambda g: g.area)
        return (_xy(np.asarray(main.exterior.coords)[:, :2]), [_xy(np.asarray(h.coords)[:, :2]) for h in main.interiors],
                len(parts))

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
    import threading
    from types import SimpleNamespace

    from tqdm import tqdm

    from jaxplan.pusharound import PushScene, build_push_world, build_wccg, connectivity, w_clear_path
    from jaxplan.pusharound.animation import animate_execution, save_final_png
    from jaxplan.pusharound.execution import ExecutionConfig, execute_schedule, plan_frames
    from jaxplan.pusharound.modetable import ModeTable
    from jaxplan.pusharound.search import SearchConfig, plan_pushes

    if not args.time_limit > 0:
        raise CLIError(f"--time-limit: must be > 0 seconds; got {args.time_limit}.")
    if args.max_replans < 0:
        raise CLIError(f"--max-replans: must be an int >= 0; got {args.max_replans}.")
    if args.max_frames < 2:
        raise CLIError(f"--max-frames: must be an int >= 2; got {args.max_frames}.")
    scene, source = _pusharound_scene(args)
    table = None
    if args.mode_table is not None and Path(args.mode_table).is_file():
        try:
            table = ModeTable.load(args.mode_table)
        except (OSError, ValueError) as exc:
            raise CLIError(f"--mode-table: {args.mode_table}: {exc}") from None
    elif args.mode_table is not None:
        table = ModeTable()
    out_dir = Path(args.out)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CLIError(f"--out: could not create {str(out_dir)!r} ({exc.strerror or exc}).") from None
    paths = {"result": out_dir / "result.json", "scene_final": out_dir / "scene_final.json",
             "figure": out_dir / "pusharound.png", "animation": out_dir / "pusharound.gif"}

    def write_result(**kw):
        try:
            _write_json(paths["result"], _pusharound_result(scene, source, args, **kw))
        except OSError as exc:
            raise CLIError(f"--out: could not write into {str(out_dir)!r} ({exc.strerror or exc}).") from None

    config = SearchConfig(time_limit_s=float(args.time_limit), backend=args.backend, seed=int(args.seed))
    world = build_push_world(scene)
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
        _atomic_write(Path(args.mode_table), lambda fh: fh.write(json.dumps(table.to_dict(), indent=1).encode()))

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
    if plan.success and not args.no_execute:
        def replan(now):
            return plan_pushes(now, config.replace(time_limit_s=max(5.0, 0.5 * float(args.time_limit))),
                               mode_table=table)

        # One element at a time: the C engine unless MJX is asked for by name.
        exec_backend = "mjx" if args.backend == "mjx" else "c"
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
            _atomic_write(Path(args.mode_table), lambda fh: fh.write(json.dumps(table.to_dict(), indent=1).encode()))
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
        _write_json(paths["scene_final"], final.to_dict())
        title = (f"{'executed' if execution is not None else 'planned'}: "
                 f"{'W-clear corridor' if path is not None else 'no W-clear path'} (W = {scene.width:g} m)")
        _atomic_write(paths["figure"], lambda fh: save_final_png(final, final.poses, final.robots, path, fh,
                                                                  title=title))
        shown = execution if execution is not None else SimpleNamespace(
            frames=plan_frames(scene, plan), executed=plan.schedule, w_clear_path=path)
        tmp = out_dir / ".pusharound.gif.tmp.gif"
        with tqdm(total=1, desc="animation", unit="frame", file=sys.stderr, leave=False) as abar:
            def tick(i, n):
                abar.total, abar.n = n, i
                abar.refresh()
            try:
                animate_execution(scene, shown, tmp, fps=args.fps, max_frames=args.max_frames, progress=tick)
                os.replace(tmp, paths["animation"])
            finally:
                if tmp.exists():
                    tmp.unlink()
    except OSError as exc:
        raise CLIError(f"--out: could not write into {str(out_dir)!r} ({exc.strerror or exc}).") from None

    st = plan.stats
    print(f"plan: {'success' if plan.success else 'failed (' + plan.reason + ')'}, {len(plan.schedule)} pushes, "
          f"{st.planning_time_s:.1f} s planning, {st.expansions} expansions, {st.simulated_pushes} simulated pushes")
    if execution is not None:
        print(f"execution: {'success' if execution.success else 'failed'} ({execution.reason}), "
              f"{len(execution.executed)} pushes, {execution.replans} replans, "
              f"{execution.execution_time_s:.1f} s simulated")
    print(f"result: {'success' if success else 'no corridor'}" + ("" if path is None else
                                                                  f", W-clear path of {len(path)} points"))
    for p in paths.values():
        print(f"wrote {p}")
    return 0


def _cmd_scenes(args) -> int:
    from jaxplan.scene import builtin_scene

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


def _cmd_sweep(args) -> int:
    from jaxplan.sweep import run_sweep

    out = run_sweep(args.spec, args.out, backend=args.backend, address=args.address,
                    memory_budget_mb=args.memory_budget_mb, progress=not args.no_progress)
    print(f"wrote {out}")
    return 0


# --------------------------------------------------------------------------------------------------
# Parser
# --------------------------------------------------------------------------------------------------

def _angle(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an angle in degrees, got {text!r}") from None


def _wrap(text: str) -> str:
    return textwrap.fill(" ".join(text.split()), width=79)


def _add_theta_option(p) -> None:
    p.add_argument("--theta-tol", type=_angle, default=60.0, metavar="DEG",
                   help="cone half-angle of the visibility rule (Eq. 1), degrees in (0, 180); default 60")


def _add_spill_options(p) -> None:
    p.add_argument("--lam", type=float, default=None, metavar="X",
                   help="spill model lambda: fraction of the load spilled per radian of turning, >= 0; "
                        "default 0.05 (0 = no spillage)")
    p.add_argument("--spill-threshold", type=float, default=_DEFAULT_SPILL_THRESHOLD, metavar="OBJ",
                   help="per-sample spills below this many objects are ignored, >= 0; default 0.001")
    p.add_argument("--capacity", type=float, default=None, metavar="OBJ",
                   help="use the capacity-aware spill model (jaxplan.spill_capacity): the blade carries at "
                        "most this many objects, > 0; default: the curvature model (no capacity)")
    p.add_argument("--mu", type=float, default=None, metavar="X",
                   help="capacity-aware model: fraction of the load lost per world unit driven, >= 0 "
                        "(implies the capacity-aware model, uncapped unless --capacity is given); "
                        "experiments/bench_rover.py fits lam, mu and capacity to the rover's physics")
    p.add_argument("--miss", type=float, default=None, metavar="X",
                   help="capacity-aware model: fraction of a cell's objects the blade leaves behind per radian "
                        "of turning at that cell, >= 0 (implies the capacity-aware model); default 0")
    p.add_argument("--turn-saturation", type=float, default=None, metavar="OBJ",
                   help="capacity-aware model: load at which the turning spill is half of lam x load per radian, "
                        "> 0 (implies the capacity-aware model); default: none (proportional to the load)")


def _add_episode_options(p) -> None:
    _add_spill_options(p)
    p.add_argument("--max-pushes", type=int, default=200, metavar="N",
                   help="push budget, >= 0; default 200")
    p.add_argument("--rearrange-margin", type=float, default=0.1, metavar="X",
                   help="choose Rearrange (connector + highway) when it collects more than (1 + X) "
                        "times the direct route; >= 0, 'inf' never rearranges; default 0.1")
    p.add_argument("--stop-fraction", type=float, default=0.02, metavar="X",
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
    p.add_argument("--fps", type=int, default=4, metavar="N", help="animation frames per second; default 4")
    p.add_argument("--no-animation", action="store_true", help="skip the GIF (faster)")


def _build_parser() -> argparse.ArgumentParser:
    fmt = argparse.RawDescriptionHelpFormatter
    scene_help = (f"a built-in scene name ({', '.join(BUILTIN_SCENES)}) or a scene file "
                  "(.npz or .json, see docs/scene-format.md)")
    parser = argparse.ArgumentParser(
        prog="jaxplan", formatter_class=fmt,
        description=_wrap("Environment-first planning for aggregate transport: build the "
                          "trajectory fabric (visibility, K-best paths, heatmap, highways) of a "
                          "scene with JAX."),
        epilog="examples:\n  jaxplan demo\n  jaxplan episode --scene corridor --out out/corridor\n"
               "  jaxplan fabric --scene corridor --out fabric.npz\n"
               "  jaxplan sweep sweep.toml --out sweep.csv\n"
               "  jaxplan scenes\n\nRun 'jaxplan COMMAND --help' for the options of a command.")
    parser.add_argument("--single-cpu", action="store_true",
                        help="run JAX on one CPU core (on the 2-core test machine about as fast up to "
                             "65x65, slower on large grids; see jaxplan.single_cpu)")
    parser.add_argument("--low-memory", action="store_true",
                        help="one malloc arena for all threads: about 20 MB less peak memory on a 65x65 "
                             "planning run (see jaxplan.limit_malloc_arenas)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser(
        "fabric", formatter_class=fmt, help="build the fabric of a scene and save its arrays (.npz)",
        description=_wrap("Load a scene, build its fabric with build_fabric and write the arrays "
                          "to a compressed .npz: " + ", ".join(FABRIC_ARRAYS) + " (table_* are "
                          "the K-best continuation table, [H, W, K]), plus target_mask, "
                          "cell_size, origin and the parameters. The file is written atomically "
                          "(temp file + rename)."),
        epilog="example:\n  jaxplan fabric --scene default --theta-tol 45 --out out/fabric.npz\n"
               "  python -c \"import numpy as np; print(np.load('out/fabric.npz')['value'].max())\"")
    p.add_argument("--scene", required=True, metavar="FILE_OR_NAME", help=scene_help)
    _add_theta_option(p)
    p.add_argument("--tau-h", type=float, default=0.5, metavar="X",
                   help="highway threshold (Eq. 11), a fraction of max heat; default 0.5")
    p.add_argument("--k", type=int, default=4, metavar="K",
                   help="depth of the continuation table (K best paths per cell); default 4")
    p.add_argument("--no-monotone", action="store_true",
                   help="drop the strict monotone rule (hop-capped DP; see docs/conventions.md)")
    p.add_argument("--out", required=True, metavar="OUT.npz", help="output file (.npz)")
    p.set_defaults(func=_cmd_fabric)

    p = sub.add_parser(
        "demo", formatter_class=fmt,
        help="the main job on a scene: fabric figure, then a whole episode (push until delivered)",
        description=_wrap("Build the fabric and the highway connectors of a scene (default: the "
                          f"built-in {DEFAULT_SCENE!r} scene) and write DIR/fabric.png "
                          "(heatmap, first-hop headings, connector headings, highways); then run an "
                          "episode on it, as 'jaxplan episode' does, writing DIR/episode.png, "
                          "DIR/episode.gif, DIR/metrics.json and DIR/metrics.csv. DIR/summary.json "
                          "holds the fabric's sizes, totals and build times and, under 'episode', "
                          "the initial mass and the final delivered, spilled and remaining mass. "
                          "The first calls compile, which takes some seconds."),
        epilog="example:\n  jaxplan demo --scene corridor --theta-tol 45 --out out/corridor")
    p.add_argument("--scene", default=DEFAULT_SCENE, metavar="NAME_OR_FILE",
                   help=scene_help + f"; default {DEFAULT_SCENE!r}")
    p.add_argument("--out", default="out/demo", metavar="DIR",
                   help="output directory (created if missing); default out/demo")
    _add_theta_option(p)
    _add_episode_options(p)
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser(
        "episode", formatter_class=fmt,
        help="run a whole transport job on a scene: plan, push, spill, rebuild until delivered",
        description=_wrap("Run an episode (docs/conventions.md, 'Episodes'): each tick picks a "
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
               "  jaxplan episode --scene my_site.json --lam 0.1 --max-pushes 50 --out out/site")
    p.add_argument("--scene", required=True, metavar="FILE_OR_NAME", help=scene_help)
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    _add_theta_option(p)
    _add_episode_options(p)
    p.set_defaults(func=_cmd_episode)

    p = sub.add_parser(
        "teams", formatter_class=fmt,
        help="simulate the earthmoving team-organization scenario, write Fig. 6 and a summary",
        description=_wrap("Simulate the scenario of Endo et al. (Section III): two loading sites "
                          "(12,000 and 8,000 kg), 10 dump trucks recruited by 2 excavators from "
                          "a waiting area, trucks slower than specified and slower still from "
                          "t = 400 s, deadline 900 s. Writes DIR/fig6.png (predicted and real "
                          "performance per team over time, with the number of trucks) and "
                          "DIR/summary.json (each team's clearing and finishing time, delivered "
                          "mass and truck-count timeline). See docs/teams.md."),
        epilog="example:\n  jaxplan teams --out out/teams\n"
               "  jaxplan teams --strategy even --v-after 1.5 --out out/teams_even")
    p.add_argument("--out", default="out/teams", metavar="DIR",
                   help="output directory (created if missing); default out/teams")
    p.add_argument("--strategy", default="performance", metavar="NAME",
                   help="performance (the paper's coordinators), even, largest (fixed shares) or "
                        "oracle (knows future velocities); default performance")
    p.add_argument("--v-after", type=float, default=1.2, metavar="M_PER_S",
                   help="truck velocity after the drop at t = 400 s, m/s > 0; default 1.2 "
                        "(before it: 3.0, spec 4.0)")
    p.add_argument("--deadline", type=float, default=900.0, metavar="S",
                   help="deadline T_DL in seconds, > 0; default 900")
    p.add_argument("--seed", type=int, default=0, metavar="N",
                   help="seed of the load-mass noise, >= 0; default 0")
    p.add_argument("--steps", type=int, default=1200, metavar="N",
                   help="simulated steps of 1 s, >= 1; default 1200")
    p.set_defaults(func=_cmd_teams)

    p = sub.add_parser(
        "rover", formatter_class=fmt,
        help="check planned routes in 3D physics: a shovel rover pushes gravel along them (MuJoCo)",
        description=_wrap("Plan on a scene (default: the built-in default scene), take the selected "
                          "routes of the --routes sources with the largest J, and drive a "
                          "differential-drive rover with a shovel along each through gravel "
                          "particles in MuJoCo (all routes in one batch; --backend c or mjx). Writes "
                          "DIR/routes.md (predicted vs simulated delivered mass, tracking error), "
                          "DIR/rover.png (top view before/after next to the 2D grids), "
                          "DIR/frames.png (rendered frames of route 0, when offscreen rendering "
                          "works) and DIR/summary.json. The predicted mass comes from the spill "
                          "model fitted to this rover's physics (jaxplan.spill_capacity.ROVER_FIT) "
                          "unless a spill option (--lam, --capacity, --mu, --miss, --turn-saturation, "
                          "--spill-threshold) is given. See docs/physics.md."),
        epilog="example:\n  jaxplan rover --out out/rover\n"
               "  jaxplan rover --scene corridor --routes 2 --backend c --out out/rover_corridor")
    p.add_argument("--scene", default=DEFAULT_SCENE, metavar="NAME_OR_FILE",
                   help=scene_help + f"; default {DEFAULT_SCENE!r}")
    p.add_argument("--out", default="out/rover", metavar="DIR",
                   help="output directory (created if missing); default out/rover")
    p.add_argument("--routes", type=int, default=4, metavar="N", help="routes to check, >= 1; default 4")
    p.add_argument("--backend", default="auto", choices=("auto", "c", "mjx"),
                   help="physics engine: c (MuJoCo C, fast on CPU), mjx (JAX, for GPUs) or auto "
                        "(mjx with a GPU, else c); default auto")
    p.add_argument("--speed", type=float, default=0.8, metavar="CELLS_PER_S",
                   help="blade speed along the route, cells/s > 0; default 0.8")
    p.add_argument("--friction", type=float, default=None, metavar="MU",
                   help="sliding friction of floor, gravel and shovel, > 0; default: the rover model's (0.6)")
    p.add_argument("--solver", default="CG", choices=("CG", "Newton"),
                   help="MuJoCo's constraint solver on either engine; default CG (faster on a CPU: C engine "
                        "2.1x, MJX 4.4x). On an H100, MJX ran 1.3-3.2x faster with Newton (docs/physics.md)")
    _add_theta_option(p)
    _add_spill_options(p)
    p.add_argument("--no-render", action="store_true", help="skip the rendered frames")
    p.set_defaults(func=_cmd_rover)

    p = sub.add_parser(
        "pusharound", formatter_class=fmt,
        help="PushAround: plan pushes that open a W-clear corridor, execute them in physics",
        description=_wrap("Collaborative path clearing (PushAround): robots push movable obstacles "
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
    p.add_argument("--seed", type=int, default=0, metavar="N",
                   help="seed of the nominal scene and of the search's gap sampling; default 0")
    p.add_argument("--backend", default="auto", choices=("auto", "c", "mjx"),
                   help="physics engine: c (MuJoCo C, fast on CPU), mjx (JAX, for GPUs) or auto "
                        "(mjx with a GPU, else c); default auto")
    p.add_argument("--time-limit", type=float, default=60.0, metavar="S",
                   help="planning time limit in seconds, > 0; default 60")
    p.add_argument("--no-execute", action="store_true",
                   help="plan only: the outputs show the planned states (no physics execution)")
    p.add_argument("--mode-table", default=None, metavar="FILE",
                   help="ModeTable JSON: validated push modes are read from it (if it exists) and "
                        "saved back after planning")
    p.add_argument("--max-replans", type=int, default=3, metavar="N",
                   help="online replans at most when a push fails in execution; default 3")
    p.add_argument("--fps", type=int, default=10, metavar="N", help="animation frames per second; default 10")
    p.add_argument("--max-frames", type=int, default=120, metavar="N",
                   help="animation frames at most (evenly subsampled), >= 2; default 120")
    p.set_defaults(func=_cmd_pusharound)

    p = sub.add_parser(
        "scenes", formatter_class=fmt, help="list the built-in scenes",
        description=_wrap("List the built-in scenes with their grid shape, target type, number "
                          "of occupied cells and total mass. Use a name with --scene."),
        epilog="example:\n  jaxplan scenes\n  jaxplan demo --scene two_targets")
    p.set_defaults(func=_cmd_scenes)

    p = sub.add_parser(
        "sweep", formatter_class=fmt,
        help="evaluate the cartesian product of a parameter sweep spec, one CSV row per setting",
        description=_wrap("Read a sweep spec (TOML: scenes, [random_scenes], [fabric] and [spill] "
                          "lists of traced parameter values, [static] fields, [metrics]; see "
                          "docs/sweeps.md), build the fabric of every setting in vmapped chunks "
                          "sized to --memory-budget-mb, and append one row per setting to OUT.csv "
                          "(setting, scene, the swept values, then the metrics). Rerunning the same "
                          "command after an interruption resumes: rows already written are kept. "
                          "--backend ray runs each chunk as a Ray task (pip install "
                          "'jaxplan[distributed]') on the cluster at --address, or on a local Ray "
                          "instance without one."),
        epilog="example:\n  jaxplan sweep sweep.toml --out out/sweep.csv\n"
               "  jaxplan sweep sweep.toml --out out/sweep.csv --backend ray --address 10.0.0.5:6379")
    p.add_argument("spec", metavar="SPEC.toml", help="the sweep spec (TOML file)")
    p.add_argument("--out", required=True, metavar="FILE.csv", help="output CSV (appended to; resumed if present)")
    p.add_argument("--backend", default="local", choices=("local", "ray"),
                   help="local (this process, default) or ray (one Ray task per chunk)")
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="Ray cluster address (with --backend ray); default: a local Ray instance")
    p.add_argument("--memory-budget-mb", type=float, default=256.0, metavar="N",
                   help="working memory for one vmapped chunk, MB (sets the chunk size); default 256")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_sweep)
    return parser


def main(argv=None) -> int:
    """Run the CLI with ``argv`` (default ``sys.argv[1:]``); returns 0 on success.

    Bad input raises ``SystemExit(2)`` after printing ``error: <message>`` to stderr (argparse's
    own usage errors exit with 2 as well).
    """
    parser = _build_parser()
    args = parser.parse_args(argv)
    try:
        if args.low_memory:
            from jaxplan._compile import limit_malloc_arenas

            limit_malloc_arenas()
        if args.single_cpu:
            from jaxplan._compile import single_cpu

            try:
                single_cpu()
            except RuntimeError as exc:
                raise CLIError(str(exc)) from None
        return args.func(args)
    except (CLIError, ValueError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT) from None
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        raise SystemExit(130) from None


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
