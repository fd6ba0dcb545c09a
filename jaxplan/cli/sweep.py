"""The ``sweep`` subcommand: a parameter sweep spec evaluated into a CSV."""
from __future__ import annotations

from jaxplan.cli.common import CLIError, check_out_file, ranged, wrap
from jaxplan.sweep import MAX_BUDGET_MB


def _cmd_sweep(args) -> int:
    from jaxplan.core import RunInterrupted, signal_number
    from jaxplan.sweep import run_sweep

    if args.address is not None and args.backend != "ray":
        raise CLIError(f"--address: {args.address!r} is only used with --backend ray; add --backend ray or drop it.")
    check_out_file(args.out)
    try:
        out = run_sweep(args.spec, args.out, backend=args.backend, address=args.address,
                        memory_budget_mb=args.memory_budget_mb, progress=not args.no_progress)
    except KeyboardInterrupt as exc:
        raise RunInterrupted(f"{args.out!r} keeps the {_rows(args.out)} complete row(s) written so far; "
                             "run the same command again to resume.", signal_number(exc)) from None
    except OSError as exc:   # a full disk or a file-size limit while appending rows
        where = exc.filename or args.out
        raise CLIError(f"--out: could not write {str(where)!r} ({exc.strerror or exc}); it keeps the "
                       f"{_rows(args.out)} complete row(s) written so far. Free space, then run the same "
                       "command again to resume.") from None
    print(f"wrote {out}")
    return 0


def _rows(path) -> int:
    try:
        with open(path, "rb") as fh:
            return max(sum(1 for _ in fh) - 1, 0)   # minus the header
    except OSError:
        return 0


def add_parsers(sub, fmt, scene_help: str) -> None:
    """Add this module's subcommands to the ``jaxplan`` parser's subparsers ``sub``."""
    p = sub.add_parser(
        "sweep", formatter_class=fmt,
        help="evaluate the cartesian product of a parameter sweep spec, one CSV row per setting",
        description=wrap("Read a sweep spec (TOML: scenes, [random_scenes], [fabric] and [spill] "
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
    p.add_argument("--memory-budget-mb", type=ranged(float, 0.0, MAX_BUDGET_MB, lo_open=True, unit="MB"),
                   default=256.0, metavar="N",
                   help=f"working memory for one vmapped chunk, MB in (0, {MAX_BUDGET_MB}] (sets the chunk size); "
                        "default 256")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_sweep)
