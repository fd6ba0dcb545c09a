"""Interrupts at random moments: each trial starts a long ``jaxplan`` command as its own process, sends
it SIGINT or SIGTERM after a random delay, and checks that it ended cleanly (issue 47).

A trial picks a command (``COMMANDS``: episode, demo, fleet of 4 rovers, rover on the C engine,
teams, a tiny sweep, pusharound without execution), runs ``python -m jaxplan.cli COMMAND ... --out
DIR`` with a fresh temp folder as its working directory, waits a delay drawn uniformly from 0 to the
command's ``max_delay`` (a few seconds beyond its compile, so compiles are hit often and some runs
finish first), sends the signal and waits for the process. It passes when:

- the exit code is 128 + the signal (or 0: the command finished before the signal), never a
  negative code (killed by a signal), 139 / 134 (a segfault or abort) or anything else;
- stderr holds no traceback nor a fatal error, and its last line starts with ``interrupted`` when
  the exit code says interrupted;
- ``DIR/run.json`` (where the command writes one) does not say ``running`` once the process has
  ended: ``interrupted`` naming the signal, or ``complete``;
- nothing was written outside DIR (the working directory holds only DIR), and DIR holds no file
  that its run.json does not list (a half-written temp file).

Writes ``experiments/results/interrupts.{json,md}``: counts per command and signal, and every
failure's details. ``--quick`` is a smoke run (one trial per command, short delays) written to the
``interrupts_quick`` stem.

    python -m experiments.interrupts --trials 200 --seed 0
    python -m experiments.interrupts --quick
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

from experiments.results_io import write_results

RESULTS_DIR = Path(__file__).resolve().parent / "results"
ROOT = Path(__file__).resolve().parent.parent
SIGNALS = {"SIGINT": signal.SIGINT, "SIGTERM": signal.SIGTERM}
WAIT_AFTER_SIGNAL_S = 120.0   # a process still alive this long after the signal counts as hung

SWEEP_SPEC = """\
scenes = ["default"]

[fabric]
theta_tol_deg = [45.0, 60.0]
tau_h = [0.3, 0.5]

[spill]
lam = [0.0, 0.05]
"""

# name -> (arguments before --out, max_delay in seconds). max_delay: a few seconds beyond the command's
# compile on a 2-core CPU, so that most trials interrupt it while it compiles or just after.
COMMANDS: dict[str, tuple[list[str], float]] = {
    "episode": (["episode", "--scene", "default", "--max-pushes", "60"], 18.0),
    "demo": (["demo", "--scene", "default", "--max-pushes", "40", "--no-animation"], 18.0),
    "fleet": (["fleet", "--scene", "default", "--rovers", "4", "--max-steps", "400", "--no-animation"], 25.0),
    "rover": (["rover", "--scene", "default", "--routes", "1", "--backend", "c", "--no-render"], 22.0),
    "teams": (["teams"], 8.0),
    "sweep": (["sweep", "SPEC", "--no-progress"], 20.0),
    "pusharound": (["pusharound", "--seed", "0", "--time-limit", "20", "--no-execute", "--max-frames", "20"], 14.0),
}
FOLDER_COMMANDS = {"episode", "demo", "fleet", "rover", "teams", "pusharound"}   # those that keep a run.json


def _argv(command: str, work: Path) -> list[str]:
    args, _ = COMMANDS[command]
    if command == "sweep":
        spec = work.parent / "spec.toml"   # the input lives beside the working directory, not in it
        spec.write_text(SWEEP_SPEC)
        return [str(spec) if a == "SPEC" else a for a in args] + ["--out", "out/sweep.csv"]
    return [*args, "--out", "out"]


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.replace("\r", "\n").splitlines() if line.strip()]
    return lines[-1] if lines else ""


def _files(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file() or p.is_symlink())


def _phase(pid: int) -> str | None:
    """Where the process stood when the signal went out, from its SIGTERM disposition in
    /proc/PID/status: "startup" (Python's default: still importing, the CLI has not installed its
    handlers), "running" (the CLI's handler), "leaving" (ignored: the exit code is decided), or None
    where /proc cannot say."""
    try:
        fields = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                      if ":" in line)
        bit = 1 << (signal.SIGTERM - 1)
        if int(fields["SigCgt"], 16) & bit:
            return "running"
        return "leaving" if int(fields["SigIgn"], 16) & bit else "startup"
    except (OSError, KeyError, ValueError):
        return None


def run_trial(command: str, signame: str, delay: float, *, wait_s: float = WAIT_AFTER_SIGNAL_S) -> dict:
    """One trial: start ``command`` (a key of COMMANDS) in a fresh temp folder, send ``signame`` after
    ``delay`` seconds, wait for the process and check how it ended. Returns the record, with
    ``ok`` and ``failures`` (the conditions it broke, empty when ok)."""
    signum = SIGNALS[signame]
    with tempfile.TemporaryDirectory(prefix="jaxplan-interrupt-") as tmp:
        work = Path(tmp) / "work"
        work.mkdir()
        argv = _argv(command, work)
        env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(ROOT)}
        started = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "jaxplan.cli", *argv], cwd=work, env=env,
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        chunks: list[bytes] = []
        reader = threading.Thread(target=lambda: chunks.extend(iter(lambda: proc.stderr.read1(65536), b"")),
                                  daemon=True)
        reader.start()
        sent, phase = False, None
        try:
            proc.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            phase = _phase(proc.pid)
            proc.send_signal(signum)
            sent = True
        sent_at = time.monotonic() - started
        hung = False
        try:
            proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            hung = True
            proc.kill()
            proc.wait()
        elapsed = time.monotonic() - started
        reader.join(timeout=10)
        err = b"".join(chunks).decode(errors="replace")
        rc = proc.returncode

        out = work / "out"
        manifest = None
        if command in FOLDER_COMMANDS:
            try:
                manifest = json.loads((out / "run.json").read_text())
            except (OSError, ValueError):
                manifest = None
        status = manifest.get("status") if isinstance(manifest, dict) else None
        out_existed = out.exists()
        outside = [f for f in _files(work) if not f.startswith("out/")]
        unlisted = []
        if isinstance(manifest, dict) and out.is_dir():
            listed = set(manifest.get("files") or []) | {"run.json"}
            unlisted = [f for f in _files(out) if f not in listed]

    last = _last_line(err)
    interrupted = rc == 128 + signum
    failures = []
    if hung:
        failures.append(f"still running {wait_s:.0f} s after the signal (killed)")
    if rc not in (0, 128 + signum):
        failures.append(f"exit code {rc}")
    if "Traceback (most recent call last)" in err:
        failures.append("traceback on stderr")
    if "Fatal Python error" in err or "Segmentation fault" in err:
        failures.append("fatal error on stderr")
    if interrupted and not last.startswith("interrupted"):
        failures.append("last stderr line is not 'interrupted: ...'")
    if status == "running":
        failures.append("run.json says 'running' after exit")
    if interrupted and status is not None and status not in ("interrupted", "complete"):
        failures.append(f"run.json says {status!r}")
    if interrupted and status == "interrupted" and signame not in str(manifest.get("error")):
        failures.append(f"run.json's error does not name {signame}")
    if rc == 0 and command in FOLDER_COMMANDS and status != "complete":
        failures.append(f"exit 0 but run.json says {status!r}")
    if outside:
        failures.append(f"files outside DIR: {outside[:5]}")
    if unlisted:
        failures.append(f"files in DIR that run.json does not list: {unlisted[:5]}")
    # Killed by the signal's default action with no output folder yet: the signal came while Python was
    # still importing jaxplan and JAX, before the CLI installed its handlers.
    # (phase "startup", read from /proc where there is one, else guessed from the exit).
    startup = phase == "startup" if phase is not None else (rc == -signum and not out_existed)
    return {"command": command, "signal": signame, "delay_s": round(delay, 3), "signal_sent": sent,
            "sent_at_s": round(sent_at, 3), "phase": phase, "elapsed_s": round(elapsed, 3), "exit_code": rc,
            "outcome": "finished" if rc == 0 else ("interrupted" if interrupted else "other"),
            "last_line": last[:300], "manifest_status": status, "files_outside": outside,
            "unlisted_in_dir": unlisted, "startup": startup, "ok": not failures, "failures": failures,
            "stderr_tail": "" if not failures else err[-3000:]}


def plan_trials(n: int, seed: int, commands: list[str], quick: bool = False) -> list[tuple[str, str, float]]:
    """``n`` trials (command, signal, delay): commands in turn, so each gets n / len(commands), with a
    random signal and a delay uniform in [0, max_delay] (quick: [0, 3] s)."""
    rng = random.Random(seed)
    plan = []
    for i in range(n):
        command = commands[i % len(commands)]
        high = 3.0 if quick else COMMANDS[command][1]
        plan.append((command, rng.choice(sorted(SIGNALS)), rng.uniform(0.0, high)))
    return plan


def summarize(trials: list[dict]) -> dict:
    per = {}
    for t in trials:
        c = per.setdefault(t["command"], Counter())
        c["trials"] += 1
        c[t["signal"]] += 1
        c[t["outcome"]] += 1
        c["failures"] += not t["ok"]
        c["startup"] += t.get("startup", False)
        c["crashes"] += (t["exit_code"] in (139, 134) or t["exit_code"] < 0) and not t.get("startup", False)
        c["running_left"] += t["manifest_status"] == "running"
        c["files_outside"] += bool(t["files_outside"])
    total = Counter()
    for c in per.values():
        total.update(c)
    return {"per_command": {k: dict(v) for k, v in per.items()}, "total": dict(total)}


def markdown(result: dict) -> str:
    s = result["summary"]
    cols = ["trials", "SIGINT", "SIGTERM", "interrupted", "finished", "other", "startup", "crashes",
            "running_left", "files_outside", "failures"]
    lines = ["# Interrupts at random moments", "",
             f"{result['date']}, {result['host']}, Python {result['python']}. Command: `{result['command']}`. "
             "Each trial runs `python -m jaxplan.cli COMMAND ... --out DIR` in a fresh temp folder, sends the "
             "signal after a delay uniform in [0, max delay] and waits for the process. interrupted = exit "
             "128 + signal; finished = exit 0 before the signal; other = any other exit (a failure); startup = "
             "the signal came before the CLI installed its handlers, while Python still imported jaxplan and JAX "
             "(from /proc/PID/status where recorded, else: killed by the signal with no output folder); "
             "crashes = any other negative exit code or 134 / 139 (startup excluded); running_left = run.json "
             "says `running` after exit; files_outside = files written outside DIR.", "",
             "| command | arguments | max delay s | " + " | ".join(cols) + " |",
             "|---|---|---:|" + "---:|" * len(cols)]
    for name, c in s["per_command"].items():
        args, high = COMMANDS[name]
        lines.append(f"| {name} | `{' '.join(args)}` | {high:g} | " + " | ".join(str(c.get(k, 0)) for k in cols) + " |")
    t = s["total"]
    lines.append("| **all** | | | " + " | ".join(f"**{t.get(k, 0)}**" for k in cols) + " |")
    failed = [x for x in result["trials"] if not x["ok"]]
    late = [x for x in result["trials"] if x["signal_sent"] and x["sent_at_s"] > 3.0]
    lines += ["", f"Signal sent more than 3 s after the start (past Python's start-up): {len(late)} trials, "
              f"{sum(not x['ok'] for x in late)} failed. Failures' signals were sent "
              + (f"{min(x['sent_at_s'] for x in failed):.2f} to {max(x['sent_at_s'] for x in failed):.2f} s "
                 "after the start." if failed else "never."),
              "", f"## Failures ({len(failed)})", ""]
    if not failed:
        lines.append("None.")
    for i, x in enumerate(failed):
        lines += [f"### {i + 1}. {x['command']}, {x['signal']} after {x['delay_s']:.2f} s: exit {x['exit_code']}", "",
                  "- " + "; ".join(x["failures"]),
                  f"- run.json status: {x['manifest_status']}; last stderr line: `{x['last_line']}`", "",
                  "```", x["stderr_tail"].strip()[-1500:], "```", ""]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.interrupts", description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=200, help="trials in all, the commands in turn (default 200)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the signals and delays (default 0)")
    ap.add_argument("--commands", nargs="+", default=list(COMMANDS), choices=list(COMMANDS))
    ap.add_argument("--jobs", type=int, default=1, help="trials run at once (default 1)")
    ap.add_argument("--time-budget", type=float, default=None, metavar="S",
                    help="start no trial after S seconds; the results say how many ran")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: one trial per command, delays in [0, 3] s, stem interrupts_quick")
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    ap.add_argument("--stem", default=None, help="results file stem (default interrupts, interrupts_quick)")
    args = ap.parse_args(argv)
    if args.trials < 1 or args.jobs < 1:
        ap.error("--trials and --jobs must be >= 1")
    n = len(args.commands) if args.quick else args.trials
    plan = plan_trials(n, args.seed, args.commands, quick=args.quick)
    stem = args.stem or ("interrupts_quick" if args.quick else "interrupts")
    command = "python -m experiments.interrupts " + " ".join(argv if argv is not None else sys.argv[1:])

    trials: list[dict] = []
    lock = threading.Lock()
    t0 = time.monotonic()
    queue = list(enumerate(plan))

    def worker():
        while True:
            with lock:
                if not queue or (args.time_budget is not None and time.monotonic() - t0 > args.time_budget):
                    return
                i, (cmd, sig, delay) = queue.pop(0)
            rec = run_trial(cmd, sig, delay)
            rec["index"] = i
            with lock:
                trials.append(rec)
                bad = sum(not t["ok"] for t in trials)
                print(f"[{len(trials)}/{len(plan)} {time.monotonic() - t0:6.0f} s] #{i} {cmd} {sig} "
                      f"@{delay:.2f}s -> exit {rec['exit_code']} ({rec['outcome']}, run.json "
                      f"{rec['manifest_status']}) {'ok' if rec['ok'] else 'FAIL: ' + '; '.join(rec['failures'])}"
                      f"  [{bad} failed so far]", flush=True)

    threads = [threading.Thread(target=worker) for _ in range(args.jobs)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    trials.sort(key=lambda t: t["index"])
    result = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "host": platform.platform(),
              "python": platform.python_version(), "command": command, "seed": args.seed,
              "trials_planned": len(plan), "trials_run": len(trials), "jobs": args.jobs,
              "wall_s": round(time.monotonic() - t0, 1),
              "commands": {k: {"arguments": COMMANDS[k][0], "max_delay_s": COMMANDS[k][1]} for k in args.commands},
              "summary": summarize(trials), "trials": trials}
    write_results(args.results_dir, stem, result, markdown(result))
    return 0 if all(t["ok"] for t in trials) else 1


if __name__ == "__main__":
    raise SystemExit(main())
