"""The ``rover`` subcommand: planned routes driven by a shovel rover in MuJoCo."""
from __future__ import annotations

import os
import sys
import time

import numpy as np

from jaxplan.cli.common import (
    MAP_SCENE_HELP,
    CLIError,
    add_site_seed_option,
    add_theta_option,
    check_fabric_memory,
    fabric_params,
    load_scene,
    ranged,
    run_folder,
    wrap,
)
from jaxplan.cli.transport import SPILL_MODEL_NAMES, add_spill_options, rover_spill_models, spill_dict, spill_params
from jaxplan.transport import DEFAULT_SCENE

MAX_ROUTES = 64          # routes per batch: each is a MuJoCo world with its own gravel particles
MIN_SPEED, MAX_SPEED = 0.05, 2.0   # cells/s: the wheel limit is 2 cells/s (rover.model); ticks grow as 1/speed
MAX_FRICTION = 5.0       # far above any floor, gravel or steel contact


def _cmd_rover(args) -> int:
    # offscreen rendering needs the EGL backend chosen before mujoco is first imported
    os.environ.setdefault("MUJOCO_GL", "egl")
    import matplotlib

    matplotlib.use("Agg")
    # the prediction the physics is compared with: a model fitted to this rover unless asked otherwise
    spill = spill_params(args, default=rover_spill_models()[args.spill_model])
    params = fabric_params(args)
    scene = load_scene(args.scene, args.site_seed)
    check_fabric_memory(args, scene, params)
    with run_folder(args) as run:
        summary = _check_and_write(args, scene, params, spill, run)
    print(summary["table"], end="")
    print(f"{len(summary['routes'])} routes x {summary['ticks']} ticks on the {summary['backend']} engine in "
          f"{summary['rollout_seconds']:.1f} s; frames: {summary['frames']}")
    for path in summary["outputs"].values():
        print(f"wrote {path}")
    return 0




def _check_and_write(args, scene, params, spill, run) -> dict:
    """Plan, roll out, plot and render; write the outputs into ``run``; returns the summary (and, under
    "table", the markdown table)."""
    import matplotlib.pyplot as plt
    from tqdm import tqdm

    from jaxplan.transport.physics import (
        RoverConfig,
        check_routes,
        plan_routes,
        plot_check,
        render_frames,
        table_markdown,
    )
    stages = ["plan (build_fabric + extract_paths)", "physics rollouts", "figure", "rendering"]
    with tqdm(total=len(stages), desc="jaxplan rover", unit="stage", file=sys.stderr, leave=False) as bar:
        bar.set_postfix_str(stages[0])
        _, routes, sources = plan_routes(scene, params, args.routes)
        bar.update()
        bar.set_postfix_str(stages[1])
        start = time.perf_counter()
        check = check_routes(scene, routes, config=RoverConfig(solver=args.solver), spill=spill,
                             speed=args.speed, backend=args.backend, friction=args.friction)
        rollout_s = time.perf_counter() - start
        bar.update()
        bar.set_postfix_str(stages[2])
        rows = check.outcome.rows()
        fig = plot_check(scene, check, route=0)
        bar.update()
        bar.set_postfix_str(stages[3])
        frames_note = None
        frames = None
        if args.no_render:
            frames_note = "skipped (--no-render)"
        else:
            try:
                frames = render_frames(check, route=0)
            except Exception as exc:  # any GL failure: report it, keep the other outputs
                frames_note = f"rendering unavailable ({type(exc).__name__}: {exc})"
        bar.update()

    b = len(rows)
    table = table_markdown(rows)
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
        "spill": spill_dict(spill),
        "spill_preset": next((name for name, fit in rover_spill_models().items() if spill is fit), None),
        "notes": ("masses in objects (1 particle = 1 object); predicted_* from the 2D push "
                  "(execute.execute_push); lateral errors in cells, blade point to spline; rollout_seconds "
                  "includes compilation on MJX"),
    }
    outputs = {}
    try:
        outputs["figure"] = run.write("rover.png", lambda fh: fig.savefig(fh, format="png", dpi=110))
        outputs["table"] = run.write("routes.md", lambda fh: fh.write(table.encode()))
        if frames is not None:
            strip = np.concatenate(list(frames), axis=1)
            outputs["frames"] = run.write("frames.png", lambda fh: plt.imsave(fh, strip, format="png"))
        summary["frames"] = frames_note or f"{len(frames)} frames of route 0 in {outputs['frames']}"
        outputs["summary"] = run.file("summary.json")
        summary["outputs"] = {k: str(v) for k, v in outputs.items()}
        run.write_json("summary.json", summary)
    except OSError as exc:
        raise CLIError(f"--out: could not write into {str(run.path)!r} ({exc.strerror or exc}).") from None
    finally:
        plt.close(fig)
    return dict(summary, table=table)


def add_parsers(sub, fmt, scene_help: str) -> None:
    """Add this module's subcommands to the ``jaxplan`` parser's subparsers ``sub``."""
    p = sub.add_parser(
        "rover", formatter_class=fmt,
        help="check planned routes in 3D physics: a shovel rover pushes gravel along them (MuJoCo)",
        description=wrap("Plan on a scene (default: the built-in default scene), take the selected "
                          "routes of the --routes sources with the largest J, and drive a "
                          "differential-drive rover with a shovel along each through gravel "
                          "particles in MuJoCo (all routes in one batch; --backend c or mjx). Writes "
                          "DIR/routes.md (predicted vs simulated delivered mass, tracking error), "
                          "DIR/rover.png (top view before/after next to the 2D grids), "
                          "DIR/frames.png (rendered frames of route 0, when offscreen rendering "
                          "works) and DIR/summary.json. The predicted mass comes from a spill "
                          "model fitted to this rover's physics (--spill-model: learned, the default, "
                          "jaxplan.transport.spillage.LEARNED_FIT; or rover-fit, ROVER_FIT) unless a "
                          "spill option (--lam, --capacity, --mu, --miss, --turn-saturation, "
                          "--spill-threshold) is given. See docs/physics.md."),
        epilog="example:\n  jaxplan rover --out out/rover\n"
               "  jaxplan rover --scene corridor --routes 2 --backend c --out out/rover_corridor\n"
               "  jaxplan rover --scene tests/data/small.map --site-seed 3 --routes 2 --out out/rover_map")
    p.add_argument("--scene", default=DEFAULT_SCENE, metavar="NAME_OR_FILE",
                   help=scene_help + MAP_SCENE_HELP + f"; default {DEFAULT_SCENE!r}")
    add_site_seed_option(p)
    p.add_argument("--out", default="out/rover", metavar="DIR",
                   help="output directory (created if missing); default out/rover")
    p.add_argument("--routes", type=ranged(int, 1, MAX_ROUTES, why="each route is one MuJoCo world with its "
                                                                 "gravel, all in one batch"),
                   default=4, metavar="N", help=f"routes to check, an int in [1, {MAX_ROUTES}]; default 4")
    p.add_argument("--backend", default="auto", choices=("auto", "c", "mjx", "warp"),
                   help="physics engine: c (MuJoCo C, fast on CPU), mjx (JAX, for GPUs) or auto "
                        "(mjx with a GPU, else c); default auto")
    p.add_argument("--speed", type=ranged(float, MIN_SPEED, MAX_SPEED, unit="cells/s",
                                          why="the rover's wheels top out at 2 cells/s, and the simulated "
                                              "horizon grows as 1/speed"),
                   default=0.8, metavar="CELLS_PER_S",
                   help=f"blade speed along the route, cells/s in [{MIN_SPEED:g}, {MAX_SPEED:g}]; default 0.8")
    p.add_argument("--friction", type=ranged(float, 0.0, MAX_FRICTION, lo_open=True,
                                             why="MuJoCo's sliding friction coefficient"),
                   default=None, metavar="MU",
                   help=f"sliding friction of floor, gravel and shovel, in (0, {MAX_FRICTION:g}]; default: the "
                        "rover model's (0.6)")
    p.add_argument("--solver", default="CG", choices=("CG", "Newton"),
                   help="MuJoCo's constraint solver on either engine; default CG (faster on a CPU); MJX on a "
                        "GPU runs faster with Newton (docs/physics.md)")
    add_theta_option(p)
    add_spill_options(p)
    p.add_argument("--spill-model", default="learned", choices=SPILL_MODEL_NAMES,
                   help="the fitted spill model the physics is compared with, when no spill option is given: "
                        "learned (LEARNED_FIT, the default) or rover-fit (ROVER_FIT, the capacity model)")
    p.add_argument("--no-render", action="store_true", help="skip the rendered frames")
    p.set_defaults(func=_cmd_rover)
