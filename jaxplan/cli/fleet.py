"""The ``fleet`` subcommand: many rovers moving aggregate on one shared fabric."""
from __future__ import annotations

from jaxplan.cli.common import (
    FPS,
    MAP_SCENE_HELP,
    CLIError,
    add_site_seed_option,
    add_theta_option,
    fabric_params,
    load_scene,
    ranged,
    run_folder,
    wrap,
)
from jaxplan.cli.transport import add_spill_options, spill_dict, spill_params

STRATEGIES = ("coordinated", "independent", "partitioned")
MAX_ROVERS = 64
MAX_STEPS = 1_000_000   # the step counter is an int32 in the compiled step; a million steps take hours


def _fleet_scene(spec: str, site_seed=None):
    """A built-in fleet site (site128, site256, site512), a built-in scene, a scene file or a .map site."""
    from jaxplan.fleet import SITES, site

    return site(spec) if spec in SITES and site_seed is None else load_scene(spec, site_seed)


def _episode_params(args):
    from jaxplan.transport import EpisodeParams, validate_episode_params

    ep = EpisodeParams(stop_fraction=args.stop_fraction, max_pushes=args.max_pushes,
                       rearrange_margin=args.rearrange_margin)
    validate_episode_params(ep)
    return ep


# the fleet's memory refusal names run_fleet's arguments; on the command line they are these flags
_FLAGS = {"n_rovers": "--rovers", "strategy": "--strategy", "scene": "--scene"}


def _check_memory(scene, config, params) -> None:
    """The fleet's memory check (fabric and rovers) before the output folder is touched, its advice in
    the command's flags."""
    from jaxplan.fleet import check_fleet_memory

    try:
        check_fleet_memory(scene.shape, config, params)
    except ValueError as exc:
        message = str(exc)
        for name, flag in _FLAGS.items():
            if message.startswith(f"{name}:"):
                message = flag + message[len(name):]
                break
        raise CLIError(message) from None


def _cmd_fleet(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from jaxplan.fleet import FleetConfig, run_fleet, summary_of, write_fleet_outputs

    params, spill, ep = fabric_params(args), spill_params(args), _episode_params(args)
    scene = _fleet_scene(args.scene, args.site_seed)
    if args.rovers > _cells_outside_targets(scene):
        raise CLIError(f"--rovers: {args.rovers} rovers do not fit on the {_cells_outside_targets(scene)} cells "
                       "outside the targets; use fewer rovers or a larger scene.")
    config = FleetConfig(args.rovers, args.strategy, clearance=args.clearance, candidates_by=args.candidates)
    _check_memory(scene, config, params)
    with run_folder(args) as run:
        fleet = run_fleet(scene, n_rovers=args.rovers, strategy=args.strategy, params=params, spill=spill,
                          episode=ep, max_steps=args.max_steps, record=not args.no_animation, progress=True,
                          config=config)
        fleet.scene_name = scene.name or args.scene     # summary.json's "scene": a file's path when unnamed
        extra = {"params": {"theta_tol_deg": float(params.theta_tol_deg), "k": int(params.k)},
                 "spill": spill_dict(spill), "max_steps": args.max_steps, "clearance": args.clearance,
                 "candidates": args.candidates}
        try:
            written = write_fleet_outputs(fleet, run, animate=not args.no_animation, fps=args.fps,
                                          extra_summary=extra)
            if args.physics:
                written["physics.json"] = run.write_json("physics.json", _physics_check(fleet, spill))
        except OSError as exc:
            raise CLIError(f"--out: could not write into {str(run.path)!r} ({exc.strerror or exc}).") from None
    summary = summary_of(fleet)
    print(f"fleet of {summary['n_rovers']} ({summary['strategy']}) on {scene.name or args.scene}: "
          f"{summary['steps']} steps, stop: {summary['stop_reason']} - {summary['message']}")
    print(f"delivered {summary['delivered']:.1f} of {summary['initial_outside']:.1f} outside the targets; "
          f"T50 {summary['T50']}, T90 {summary['T90']}; conflicts {summary['conflicts']}")
    for path in written.values():
        print(f"wrote {path}")
    return 0


def _cells_outside_targets(scene) -> int:
    import numpy as np

    return int((~np.asarray(scene.target_mask)).sum())


def _physics_check(fleet, spill) -> dict:
    """The first round of concurrent pushes (every rover's first push) driven in one MuJoCo world."""
    from jaxplan.fleet import check_first_round

    return check_first_round(fleet, spill)


def add_parsers(sub, fmt, scene_help: str) -> None:
    """Add this module's subcommand to the ``jaxplan`` parser's subparsers ``sub``."""
    p = sub.add_parser(
        "fleet", formatter_class=fmt,
        help="many rovers push aggregate toward the targets on one shared fabric, without collisions",
        description=wrap("Run a fleet of N rovers on a scene until the mass outside the targets falls "
                         "under --stop-fraction, --max-pushes pushes are spent or --max-steps steps pass. "
                         "Every rover occupies one cell and moves one cell per step; idle rovers are "
                         "given pushes from the shared fabric (--strategy: coordinated, the fleet's "
                         "planner; independent, each rover for itself; partitioned, one sector each), "
                         "and the fabric is rebuilt when pushes end. Writes DIR/summary.json (mass, "
                         "T50 / T90, pushes and idle time per rover, planning ms per event, conflicts), "
                         "DIR/trajectory.npz, DIR/pushes.json, DIR/fleet.png, DIR/fleet.gif and, with "
                         "--physics, DIR/physics.json. See docs/fleet.md."),
        epilog="example:\n  jaxplan fleet --scene site128 --rovers 8 --out out/fleet8\n"
               "  jaxplan fleet --scene default --rovers 2 --strategy independent --no-animation --out out/f2\n"
               "  jaxplan fleet --scene tests/data/small.map --site-seed 3 --rovers 2 --out out/fleet_map")
    p.add_argument("--scene", required=True, metavar="NAME_OR_FILE",
                   help=scene_help + "; or a fleet site: site128, site256, site512" + MAP_SCENE_HELP)
    add_site_seed_option(p)
    p.add_argument("--rovers", type=ranged(int, 1, MAX_ROVERS, why="the fleet's arrays are sized for it"),
                   default=4, metavar="N", help=f"number of rovers, an int in [1, {MAX_ROVERS}]; default 4")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    p.add_argument("--strategy", default="coordinated", choices=STRATEGIES,
                   help="coordinated (default), independent or partitioned (docs/fleet.md)")
    p.add_argument("--max-steps", type=ranged(int, 1, MAX_STEPS, why="the step counter is an int32"),
                   default=5000, metavar="T", help="simulated steps at most; default 5000")
    p.add_argument("--max-pushes", type=ranged(int, 0, 1_000_000, why="the push counter is an int32"),
                   default=100_000, metavar="N", help="pushes at most, all rovers together; default 100000")
    p.add_argument("--stop-fraction", type=ranged(float, 0.0, 1.0, hi_open=True), default=0.02, metavar="X",
                   help="stop when the mass outside the targets is at most X of its initial value, in [0, 1); "
                        "default 0.02")
    p.add_argument("--rearrange-margin", type=ranged(float, 0.0, inf_ok=True), default=0.1, metavar="X",
                   help="a push goes via a highway when that collects more than (1 + X) times the direct "
                        "route; >= 0, 'inf' never; default 0.1")
    add_theta_option(p)
    add_spill_options(p)
    p.add_argument("--candidates", choices=("value", "rate"), default="value",
                   help="coordinated candidates: the top sources by J (value), or each idle rover's best "
                        "sources by J over its approach and route length (rate); default value")
    p.add_argument("--clearance", type=int, choices=(0, 1, 2), default=0,
                   help="cells a task reserves: 0 the cells its push changes, 1 one more cell around its "
                        "route, 2 the rover's body (no rover-rover contact in physics); default 0")
    p.add_argument("--physics", action="store_true",
                   help="drive the first round of concurrent pushes in one MuJoCo world with gravel and report "
                        "rover-rover contacts and simulated vs predicted delivery (DIR/physics.json)")
    p.add_argument("--fps", type=FPS, default=8, metavar="N",
                   help="animation frames per second, an int in [1, 50]; default 8")
    p.add_argument("--no-animation", action="store_true", help="skip the GIF (faster)")
    p.set_defaults(func=_cmd_fleet)
