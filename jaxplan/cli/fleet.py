"""The ``fleet`` subcommand: many rovers moving aggregate on one shared fabric."""
from __future__ import annotations

import json

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
from jaxplan.cli.transport import add_spill_options, rover_spill_models, spill_dict, spill_params

STRATEGIES = ("coordinated", "independent", "partitioned")
MAX_ROVERS = 1024
MAX_STEPS = 1_000_000   # the step counter is an int32 in the compiled step; a million steps take hours
# --starts: a JSON list of 64 [row, col] pairs takes about 1 kB; anything much longer is the wrong file
MAX_STARTS_BYTES = 64 * 1024
STARTS_WHAT = "a JSON list of [row, col] start cells, one per rover, e.g. [[0, 0], [0, 24]]"
# --physics prints one line per push of the round up to this many; physics.json holds them all
_PHYSICS_ROWS = 16


def _fleet_scene(spec: str, site_seed=None):
    """A built-in fleet site (site128, site256, site512, site1024), a built-in scene, a scene file or a .map site."""
    from jaxplan.fleet import SITES, site

    return site(spec) if spec in SITES and site_seed is None else load_scene(spec, site_seed)


def _episode_params(args):
    from jaxplan.transport import EpisodeParams, validate_episode_params

    ep = EpisodeParams(stop_fraction=args.stop_fraction, max_pushes=args.max_pushes,
                       rearrange_margin=args.rearrange_margin)
    validate_episode_params(ep)
    return ep


# run_fleet's refusals name its arguments; on the command line they are these flags
_FLAGS = {"n_rovers": "--rovers", "strategy": "--strategy", "scene": "--scene", "max_steps": "--max-steps"}


def _read_starts(path: str, n_rovers: int):
    """``--starts FILE``: the start cells ``i64[n_rovers, 2]`` (row, col) of a JSON list of pairs.

    Every problem with the file is a ``CLIError`` naming ``--starts`` and the file: unreadable (missing,
    a folder, no permission, empty, not UTF-8, longer than ``MAX_STARTS_BYTES``), not JSON, not a list
    of [row, col] pairs, not integers, or not one pair per rover. Where the cells lie (in the grid,
    distinct, outside the targets, not blocked, not cut off) is ``run_fleet``'s check
    (:func:`_check_inputs`)."""
    import numpy as np

    from jaxplan.core import read_text, shown_path

    where = f"--starts: {shown_path(path)}:"
    try:
        text = read_text(path, STARTS_WHAT, max_bytes=MAX_STARTS_BYTES)
    except ValueError as exc:
        raise CLIError(f"{where} {exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CLIError(f"{where} is not JSON (line {exc.lineno}, column {exc.colno}: {exc.msg}); expected "
                       f"{STARTS_WHAT}.") from None
    except RecursionError:
        raise CLIError(f"{where} nests lists too deeply; expected {STARTS_WHAT}.") from None
    if not isinstance(data, list):
        raise CLIError(f"{where} holds a JSON {_json_type(data)}, not a list; expected {STARTS_WHAT}.")
    for k, cell in enumerate(data):
        if not isinstance(cell, list) or len(cell) != 2:
            raise CLIError(f"{where} entry {k} ({_shown_json(cell)}) is not a [row, col] pair; expected "
                           f"{STARTS_WHAT}.")
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in cell):
            raise CLIError(f"{where} entry {k} ({_shown_json(cell)}): a cell's row and col are whole numbers "
                           f"(JSON integers such as 3, not 3.0, \"3\" or true); expected {STARTS_WHAT}.")
        if not all(-2**31 <= v < 2**31 for v in cell):
            raise CLIError(f"{where} entry {k} ({_shown_json(cell)}) lies far outside the grid; give cells of the "
                           "grid (row 0 is the bottom row, col 0 the left column).")
    if len(data) != n_rovers:
        raise CLIError(f"{where} holds {len(data)} start cell(s) for {n_rovers} rover(s) (--rovers {n_rovers}); "
                       "give one [row, col] pair per rover.")
    return np.asarray(data, np.int64).reshape(n_rovers, 2)


def _json_type(value) -> str:
    return {dict: "object", str: "string", bool: "boolean", type(None): "null"}.get(type(value), "number")


def _shown_json(value) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _check_inputs(scene, config, params, spill, episode, args, starts) -> None:
    """``run_fleet``'s own checks (the scene, the settings, the start cells, the memory the fabric and
    the rovers need) before the output folder is touched, in the command's flags: a refusal of
    ``starts`` names ``--starts`` and its file, the memory's advice names ``--rovers``, ``--strategy`` or
    ``--scene``."""
    from jaxplan.core import shown_path
    from jaxplan.fleet import validate_fleet_inputs

    try:
        validate_fleet_inputs(scene, config.n_rovers, config.strategy, params, spill, episode, args.max_steps,
                              starts, config)
    except ValueError as exc:
        message = str(exc)
        if message.startswith("starts:"):
            raise CLIError(f"--starts: {shown_path(args.starts)}:{message[len('starts:'):]}") from None
        for name, flag in _FLAGS.items():
            if message.startswith(f"{name}:"):
                message = flag + message[len(name):]
                break
        raise CLIError(message) from None


def _cmd_fleet(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from jaxplan.fleet import FleetConfig, run_fleet, summary_of, write_fleet_outputs

    params, ep = fabric_params(args), _episode_params(args)
    # with --physics the fleet plans and predicts with the model fitted to the MuJoCo rover, so that
    # the check compares physics with that rover's prediction
    spill = spill_params(args, default=rover_spill_models()["learned"] if args.physics else None)
    scene = _fleet_scene(args.scene, args.site_seed)
    if args.rovers > _cells_outside_targets(scene):
        raise CLIError(f"--rovers: {args.rovers} rovers do not fit on the {_cells_outside_targets(scene)} cells "
                       "outside the targets; use fewer rovers or a larger scene.")
    starts = None if args.starts is None else _read_starts(args.starts, args.rovers)
    config = FleetConfig(args.rovers, args.strategy, clearance=args.clearance, candidates_by=args.candidates)
    _check_inputs(scene, config, params, spill, ep, args, starts)
    physics = None
    with run_folder(args) as run:
        fleet = run_fleet(scene, n_rovers=args.rovers, strategy=args.strategy, params=params, spill=spill,
                          episode=ep, max_steps=args.max_steps, starts=starts, record=not args.no_animation,
                          progress=True, config=config)
        fleet.scene_name = scene.name or args.scene     # summary.json's "scene": a file's path when unnamed
        extra = {"params": {"theta_tol_deg": float(params.theta_tol_deg), "k": int(params.k)},
                 "spill": spill_dict(spill), "max_steps": args.max_steps, "clearance": args.clearance,
                 "candidates": args.candidates}
        try:
            written = write_fleet_outputs(fleet, run, animate=not args.no_animation, fps=args.fps,
                                          extra_summary=extra)
            if args.physics:
                physics = _physics_check(fleet, spill)
                written["physics.json"] = run.write_json("physics.json", physics)
        except OSError as exc:
            raise CLIError(f"--out: could not write into {str(run.path)!r} ({exc.strerror or exc}).") from None
    summary = summary_of(fleet)
    print(f"fleet of {summary['n_rovers']} ({summary['strategy']}) on {scene.name or args.scene}: "
          f"{summary['steps']} steps, stop: {summary['stop_reason']} - {summary['message']}")
    print(f"delivered {summary['delivered']:.1f} of {summary['initial_outside']:.1f} outside the targets; "
          f"T50 {summary['T50']}, T90 {summary['T90']}; conflicts {summary['conflicts']}")
    print(timing_line(summary))
    if physics is not None:
        for line in physics_lines(physics):
            print(line)
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


def _objects(value) -> str:
    return "n/a" if value is None else f"{value:.1f}"


def physics_lines(result: dict) -> list[str]:
    """What ``--physics`` found, for stdout: the round, its rover-rover contacts and closest approach,
    one line per push (simulated against predicted delivered mass, the relative error and whether it
    is within the tolerance; at most ``_PHYSICS_ROWS``, the rest in physics.json), and how many pushes
    agree. ``result``: ``check_first_round``'s dict (physics.json)."""
    if not result.get("rovers"):
        return [f"physics: {result.get('note', 'nothing to check')}"]
    rows = result["pushes"]
    tolerance = float(result["tolerance"])
    closest = result.get("min_axle_distance_cells")
    lines = [f"physics: the first round of {len(rows)} concurrent push(es) in one MuJoCo world: "
             f"{result['contacts']} rover-rover contact step(s)"
             + (f", closest axles {closest:.2f} cells apart" if closest is not None else "")]
    for row in rows[:_PHYSICS_ROWS]:
        err = row.get("relative_error")
        verdict = ("no prediction to compare" if err is None else
                   f"{err:.0%} off, {'within' if row['within'] else 'outside'} {tolerance:.0%}")
        lines.append(f"  rover {row['rover']}: delivered {_objects(row['delivered'])} simulated vs "
                     f"{_objects(row['predicted_delivered'])} predicted objects ({verdict})"
                     + ("" if row.get("reached", True) else "; did not reach its route's end"))
    if len(rows) > _PHYSICS_ROWS:
        lines.append(f"  ... {len(rows) - _PHYSICS_ROWS} more push(es) in physics.json")
    within = sum(bool(row["within"]) for row in rows)
    lines.append(f"  {within} of {len(rows)} push(es) within {tolerance:.0%} of the predicted delivery"
                 + ("" if result.get("finite", True) else "; the physics diverged (see physics.json)"))
    return lines


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
                         "DIR/trajectory.npz, DIR/pushes.json, DIR/fleet.png (mass over time with T50 / T90, "
                         "the initial piles and rover starts, the traffic per cell, the final counts), "
                         "DIR/fleet.gif (the mass, rovers and routes step by step) and, with --physics, "
                         "DIR/physics.json (also printed). See docs/fleet.md."),
        epilog="example:\n  jaxplan fleet --scene site128 --rovers 8 --out out/fleet8\n"
               "  jaxplan fleet --scene default --rovers 2 --strategy independent --no-animation --out out/f2\n"
               "  jaxplan fleet --scene tests/data/small.map --site-seed 3 --rovers 2 --out out/fleet_map\n"
               "  echo '[[0, 0], [24, 0]]' > starts.json   # [row, col] per rover; row 0 is the bottom row\n"
               "  jaxplan fleet --scene default --rovers 2 --starts starts.json --out out/f2_starts")
    p.add_argument("--scene", required=True, metavar="NAME_OR_FILE",
                   help=scene_help + "; or a fleet site: site128, site256, site512, site1024" + MAP_SCENE_HELP)
    add_site_seed_option(p)
    p.add_argument("--rovers", type=ranged(int, 1, MAX_ROVERS, why="the fleet's arrays are sized for it"),
                   default=4, metavar="N", help=f"number of rovers, an int in [1, {MAX_ROVERS}]; default 4")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    p.add_argument("--starts", default=None, metavar="FILE",
                   help="the rovers' start cells: a JSON file holding one [row, col] pair per rover (row 0 is the "
                        "bottom row, col 0 the left column), e.g. [[0, 0], [24, 0]] for --rovers 2; cells in "
                        "the grid, distinct, outside the targets, not blocked and not cut off from every target; "
                        "default: spread along the border (one per sector with --strategy partitioned)")
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
    p.add_argument("--candidates", choices=("value", "rate"), default="rate",
                   help="coordinated candidates: each idle rover's best sources by J over its approach and "
                        "route length (rate), or the top sources by J (value); default rate")
    p.add_argument("--clearance", type=int, choices=(0, 1, 2), default=0,
                   help="cells a task reserves: 0 the cells its push changes, 1 one more cell around its "
                        "route, 2 the rover's body (no rover-rover contact in physics); default 0")
    p.add_argument("--physics", action="store_true",
                   help="drive the first round of concurrent pushes in one MuJoCo world with gravel and report "
                        "rover-rover contacts and simulated vs predicted delivery per push (printed, and in "
                        "DIR/physics.json); without a spill option the fleet then plans and predicts with the "
                        "spill model fitted to the MuJoCo rover (LEARNED_FIT)")
    p.add_argument("--fps", type=FPS, default=8, metavar="N",
                   help="animation frames per second, an int in [1, 50]; default 8")
    p.add_argument("--no-animation", action="store_true", help="skip the GIF (faster)")
    p.set_defaults(func=_cmd_fleet)


def timing_line(summary: dict) -> str:
    """One line of the step's times (median / p95 ms over every step) beside a full build's."""
    def ms(key):
        value = summary[key]
        return "-" if value["median"] is None else f"{value['median']:.1f} / {value['p95']:.1f}"

    build = summary["full_build_ms"]
    return (f"ms per step (median / p95): step {ms('step_ms')}, planning {ms('plan_ms')}, fabric refresh "
            f"{ms('refresh_ms')}; one full fabric build {'-' if build is None else f'{build:.1f}'}")
