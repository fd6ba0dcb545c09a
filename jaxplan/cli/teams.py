"""The ``teams`` subcommand: the team-organization scenario of Endo et al."""
from __future__ import annotations

from jaxplan.cli.common import SEED, check_out_dir, ranged, run_folder, wrap
from jaxplan.teams import STRATEGIES

MAX_V_AFTER = 50.0    # m/s (180 km/h): far above any dump truck; the spec speed is 4 m/s
MAX_SECONDS = 86_400  # s: a day of 1 s steps; the trace is recorded every step


def _cmd_teams(args) -> int:
    import matplotlib

    matplotlib.use("Agg")  # writes files only; works without a display
    from jaxplan.teams import check_paper_options, run_paper

    check_paper_options(args.strategy, args.v_after, args.deadline, args.seed, args.steps)
    check_out_dir(args.out)
    with run_folder(args) as run:
        summary = run_paper(run.path, strategy=args.strategy, seed=args.seed, v_after=args.v_after,
                            deadline=args.deadline, steps=args.steps, write=run.write)
    for team in summary["teams"]:
        print(f"team {team['team']}: cleared at {team['clear_time_s']} s, delivered "
              f"{team['delivered_kg']:g} of {team['initial_mass_kg']:g} kg (last at "
              f"{team['finishing_time_s']} s), up to {team['max_trucks']} trucks")
    print(f"deadline {summary['deadline_s']:g} s met: {summary['deadline_met']}; "
          f"peak {summary['peak_trucks']} trucks")
    print(f"wrote {summary['outputs']['figure']}")
    print(f"wrote {summary['outputs']['summary']}")
    return 0


def add_parsers(sub, fmt, scene_help: str) -> None:
    """Add this module's subcommands to the ``jaxplan`` parser's subparsers ``sub``."""
    p = sub.add_parser(
        "teams", formatter_class=fmt,
        help="simulate the earthmoving team-organization scenario, write Fig. 6 and a summary",
        description=wrap("Simulate the scenario of Endo et al. (Section III): two loading sites "
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
    p.add_argument("--strategy", default="performance", choices=STRATEGIES, metavar="NAME",
                   help="performance (the paper's coordinators), even, largest (fixed shares) or "
                        "oracle (knows future velocities); default performance")
    p.add_argument("--v-after", type=ranged(float, 0.0, MAX_V_AFTER, lo_open=True, unit="m/s"), default=1.2,
                   metavar="M_PER_S", help=f"truck velocity after the drop at t = 400 s, m/s in (0, {MAX_V_AFTER:g}]; "
                                           "default 1.2 (before it: 3.0, spec 4.0)")
    p.add_argument("--deadline", type=ranged(float, 0.0, MAX_SECONDS, lo_open=True, unit="s"), default=900.0,
                   metavar="S", help=f"deadline T_DL in seconds, in (0, {MAX_SECONDS}]; default 900")
    p.add_argument("--seed", type=SEED, default=0, metavar="N",
                   help="seed of the load-mass noise, an int in [0, 2^32 - 1]; default 0")
    p.add_argument("--steps", type=ranged(int, 1, MAX_SECONDS, why="a day of 1 s steps; the trace is recorded "
                                                                  "every step"),
                   default=1200, metavar="N",
                   help=f"simulated steps of 1 s, an int in [1, {MAX_SECONDS}]; default 1200")
    p.set_defaults(func=_cmd_teams)
