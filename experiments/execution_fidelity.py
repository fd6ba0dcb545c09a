"""Execution fidelity: how closely pushes executed in physics (Section III-D) follow the plan.

Replays the schedules of ``jaxplan pusharound`` result files with
:func:`jaxplan.pusharound.execution.execute_schedule` WITHOUT replanning (so every planned push is
executed, also after a deviation) and reports per push: the stop reason (early stop at the planned
pose, stall, horizon), validity, the pushed movable's centroid and yaw error against its predicted
pose, the largest Hausdorff distance of any movable's outline from its predicted outline (the
execution's failure measure), the transit and push seconds (table: the worst push of each schedule);
per schedule: simulated time, wall time, and whether Eq. 7 holds at the end. A failed search's
partial schedule replays as well (the result file keeps it).

The scene of each result file is rebuilt from its ``scene.source`` (``nominal_scene(seed=N)`` or a
scene file path). Wall times are on whatever CPU runs the script: indicative only; the ratio
simulated / wall is printed side by side in one run.

Results: a markdown table on stdout, ``experiments/results/execution_fidelity.json`` and ``.md``.

Example::

    jaxplan pusharound --seed 1 --time-limit 150 --no-execute --out out/pa1
    python -m experiments.execution_fidelity out/pa1/result.json out/tiny/result.json
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import platform
import re
import sys
import time
from pathlib import Path

import numpy as np

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def _scene_of(result: dict, result_path: Path):
    from jaxplan.pusharound import PushScene, nominal_scene

    src = result["scene"]["source"]
    m = re.fullmatch(r"nominal_scene\(seed=(-?\d+)\)", src)
    if m:
        return nominal_scene(int(m.group(1)))
    path = Path(src)
    if not path.is_absolute() and not path.exists():
        path = result_path.parent / path
    return PushScene.load(path)


def replay(result_path: Path) -> dict:
    from jaxplan.pusharound.execution import execute_schedule, load_schedule

    result = json.loads(result_path.read_text())
    scene = _scene_of(result, result_path)
    schedule = load_schedule(result)
    t0 = time.perf_counter()
    ex = execute_schedule(scene, schedule)
    wall = time.perf_counter() - t0
    def target_error(e):
        m = int(np.asarray(e.task.movable))
        return round(float(np.linalg.norm(e.poses_after[m, :2] - e.planned[m, :2])), 4), \
            round(float(abs(np.angle(np.exp(1j * (e.poses_after[m, 2] - e.planned[m, 2]))))), 4)

    pushes = [{"movable": int(np.asarray(e.task.movable)), "stop": e.stop, "valid": bool(e.valid),
               "invalid": e.invalid, "ok": bool(e.ok),
               "target_centroid_error_m": target_error(e)[0], "target_yaw_error_rad": target_error(e)[1],
               "deviation_m": None if not np.isfinite(e.deviation) else round(float(e.deviation), 4),
               "transit_s": round(e.transit_s, 3), "push_s": round(e.push_s, 3)} for e in ex.executed]
    return {"result_file": str(result_path), "scene": result["scene"]["source"],
            "planned_success": bool(result["planning"]["success"]) if result.get("planning") else None,
            "pushes_planned": len(schedule), "pushes_executed": len(ex.executed), "reason": ex.reason,
            "connected": bool(ex.connectivity), "simulated_s": round(ex.execution_time_s, 3),
            "wall_s": round(wall, 3), "pushes": pushes}


def table(rows: list) -> str:
    out = ["| scene | planned ok | pushes | stops | target centroid error [m] | target yaw error [rad] | "
           "outline deviation [m] | all valid | Eq. 7 at end | simulated [s] | wall [s] | sim / wall |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def top(r, key):
        v = [p[key] for p in r["pushes"] if p[key] is not None and p["stop"] != "transit_timeout"]
        return f"{max(v):.3f}" if v else "-"

    for r in rows:
        stops = ", ".join(p["stop"] for p in r["pushes"]) or "-"
        out.append(f"| {r['scene']} | {r['planned_success']} | {r['pushes_executed']}/{r['pushes_planned']} "
                   f"| {stops} | "
                   f"{top(r, 'target_centroid_error_m')} | {top(r, 'target_yaw_error_rad')} | "
                   f"{top(r, 'deviation_m')} | {all(p['valid'] for p in r['pushes'])} | "
                   f"{r['connected']} | {r['simulated_s']:.1f} | {r['wall_s']:.1f} | "
                   f"{r['simulated_s'] / max(r['wall_s'], 1e-9):.1f} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.execution_fidelity", description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="result.json files of `jaxplan pusharound`")
    ap.add_argument("--name", default="execution_fidelity", help="output stem under experiments/results/")
    args = ap.parse_args(argv)
    rows = [replay(p) for p in args.results]
    md = table(rows)
    note = ("Replayed without replanning, C engine; wall clock on this machine "
            "(indicative only); the first row includes the one-off jit of the two controllers.")
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    meta = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "python": sys.version.split()[0],
            "machine": platform.machine(), "note": note}
    (RESULTS_DIR / f"{args.name}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    (RESULTS_DIR / f"{args.name}.md").write_text(f"# Execution fidelity\n\n{note}\n\n{md}")
    print(md, end="")
    print(note)
    return 0


if __name__ == "__main__":
    sys.exit(main())
