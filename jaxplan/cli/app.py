"""The ``jaxplan`` command line: ``fabric``, ``demo``, ``episode``, ``teams``, ``rover``, ``pusharound``,
``sweep`` and ``scenes``.

Every subcommand has ``--help`` with an example. Bad input (a missing scene file, an unknown built-in
name, an out-of-range parameter) prints one ``error: --flag: ...`` line to stderr and exits with code
2, before any work starts and before any output is written: flag values are checked as they are
parsed (``common.ranged``, ``common.Parser``), the rest (scene files, parameter combinations,
estimated memory) by each command before it starts.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from typing import NoReturn

from jaxplan.cli import fleet, pusharound, rover, sweep, teams, transport
from jaxplan.cli.common import EXIT_BAD_INPUT, CLIError, Parser, wrap
from jaxplan.core import INTERRUPT_SIGNALS, shown_path, signal_number, stop_signals_interrupt
from jaxplan.transport import BUILTIN_SCENES

__all__ = ["entry", "main"]


def build_parser() -> argparse.ArgumentParser:
    fmt = argparse.RawDescriptionHelpFormatter
    scene_help = (f"a built-in scene name ({', '.join(BUILTIN_SCENES)}) or a scene file "
                  "(.npz or .json, see docs/scene-files.md)")
    parser = Parser(
        prog="jaxplan", formatter_class=fmt,
        description=wrap("Plan how robots move bulk material and clear paths on a construction "
                         "site: environment-first aggregate transport (fabric, demo, episode, fleet, rover, "
                         "sweep, scenes), PushAround path clearing (pusharound) and team organization "
                         "(teams), as jit-compiled JAX kernels."),
        epilog="examples:\n  jaxplan demo\n  jaxplan episode --scene corridor --out out/corridor\n"
               "  jaxplan fabric --scene corridor --out fabric.npz\n"
               "  jaxplan fleet --scene site128 --rovers 8 --out out/fleet\n"
               "  jaxplan pusharound --seed 3 --out out/push3\n  jaxplan teams --out out/teams\n"
               "  jaxplan sweep sweep.toml --out sweep.csv\n"
               "  jaxplan scenes\n\nRun 'jaxplan COMMAND --help' for the options of a command.")
    parser.add_argument("--single-cpu", action="store_true",
                        help="run JAX on one CPU core (often as fast on small grids, slower on large "
                             "ones; see jaxplan.single_cpu)")
    parser.add_argument("--low-memory", action="store_true",
                        help="one malloc arena for all threads: less peak memory "
                             "(see jaxplan.limit_malloc_arenas)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for system in (transport, fleet, teams, rover, pusharound, sweep):
        system.add_parsers(sub, fmt, scene_help)
    return parser


def main(argv=None) -> int:
    """Run the CLI with ``argv`` (default ``sys.argv[1:]``); returns 0 on success.

    Bad input raises ``SystemExit(2)`` after printing one ``error: <message>`` line to stderr
    (argparse's own usage errors too, through ``common.Parser``). Ctrl-C, SIGTERM and SIGHUP raise
    ``SystemExit(128 + signal)`` (130 for Ctrl-C) after printing ``interrupted: <where the partial
    output is>``; the output folder's run.json says "interrupted" and names the signal. An interrupt
    that a callback swallowed prints no traceback (it is raised again at the next step). As a process,
    use :func:`entry`, which also leaves without the interpreter's teardown after an interrupt.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with stop_signals_interrupt(), _quiet_swallowed_interrupts():
            return _run(args)
    except KeyboardInterrupt as exc:   # raised again as the handlers came off (it was swallowed at the end)
        _interrupted(exc)


def entry(argv=None) -> NoReturn:
    """The command line as a whole process (``python -m jaxplan.cli``): run :func:`main`, then end the
    process with its exit code; unlike ``main`` it never returns.

    An interrupt before ``main`` installs its handlers (while the arguments are read) or after it
    removes them (while the command returns) exits with ``128 + signal`` too, not with Python's
    default (a traceback, or death by the signal); once the command's exit code is known, a signal
    changes nothing. After an interrupt the process leaves with ``os._exit`` as soon as stdout and
    stderr are flushed: XLA's compile threads may still be running, and tearing the interpreter down
    under them segfaults (exit 139 after the ``interrupted:`` line; issue 47). Nothing is lost by
    skipping the teardown: every output file is complete and the folder's run.json already says
    "interrupted".
    """
    code = None
    try:
        with stop_signals_interrupt():
            try:
                code = main(argv)
            except SystemExit as exc:
                code = exc.code
    except KeyboardInterrupt as exc:
        if code is None:   # before main's own handlers, or as they came off
            code = 128 + signal_number(exc)
            print("interrupted", file=sys.stderr)
    for s in INTERRUPT_SIGNALS:   # the outcome is decided: leave without being cut short
        signal.signal(s, signal.SIG_IGN)
    if code is None:
        code = 0
    elif not isinstance(code, int):   # SystemExit("message"), as sys.exit prints it
        print(code, file=sys.stderr)
        code = 1
    with contextlib.suppress(Exception):
        sys.stdout.flush()
    with contextlib.suppress(Exception):
        sys.stderr.flush()
    if code > 128 and code - 128 in INTERRUPT_SIGNALS:
        os._exit(code)
    sys.exit(code)


@contextlib.contextmanager
def _quiet_swallowed_interrupts():
    """Within the block, an interrupt that a callback swallowed (Python prints it as "Exception ignored
    in ...", a traceback) is not printed: ``check_interrupt`` raises it again at the next step, so it
    is not lost. Other swallowed exceptions are printed as before."""
    previous = sys.unraisablehook

    def hook(unraisable):
        if not isinstance(unraisable.exc_value, KeyboardInterrupt):
            previous(unraisable)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous


def _interrupted(exc: KeyboardInterrupt) -> NoReturn:
    """Print ``interrupted: <where the partial output is>`` and exit with 128 + the signal."""
    detail = " ".join(str(exc).split())
    print(f"interrupted: {detail}" if detail else "interrupted", file=sys.stderr)
    raise SystemExit(128 + signal_number(exc)) from None


def _run(args) -> int:
    try:
        if args.low_memory:
            from jaxplan.core import limit_malloc_arenas

            limit_malloc_arenas()
        if args.single_cpu:
            from jaxplan.core import single_cpu

            try:
                single_cpu()
            except RuntimeError as exc:
                raise CLIError(str(exc)) from None
        return args.func(args)
    except (CLIError, ValueError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT) from None
    except OSError as exc:   # the file system refused a path the checks could not foresee (a full disk)
        where = shown_path(exc.filename) + ": " if exc.filename else ""
        print(f"error: {where}{exc.strerror or exc}; check the path and the free space.", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT) from None
    except KeyboardInterrupt as exc:   # RunInterrupted says where the partial output is
        _interrupted(exc)
