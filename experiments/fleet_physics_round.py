"""The fleet's own concurrent pushes in physics, by clearance: what ``jaxplan fleet --physics`` checks.

For each clearance (0, 1, 2) a coordinated fleet of ``--rovers`` runs on the site for ``--steps``
steps with a spill model fitted to the MuJoCo rover (``--spill-model``: ``LEARNED_FIT``, the default of
``jaxplan rover`` and ``jaxplan fleet --physics``, or ``ROVER_FIT``);
its first full round of concurrent pushes (``physics.first_round``: the most tasks running at one
step, so their footprints are pairwise disjoint) is then driven at once in one MuJoCo world with
gravel (``physics.check_first_round``, C engine): rover-rover contacts, and each push's simulated
delivery against the 2D model's, within 15% or not.

    python -m experiments.fleet_physics_round                      # site128, 4 rovers, clearances 0 1 2
    python -m experiments.fleet_physics_round --clearances 2 --rovers 8

Results: ``experiments/results/fleet_physics_round.{json,md}`` (``--name`` sets the stem).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import platform
import time
from pathlib import Path

from experiments.results_io import write_results
from jaxplan import FabricParams
from jaxplan.fleet import FleetConfig, check_first_round, run_fleet, site
from jaxplan.transport import EpisodeParams
from jaxplan.transport.spillage import ROVER_MODELS

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def _one(scene, n: int, clearance: int, steps: int, spill) -> dict:
    config = FleetConfig(n, "coordinated", clearance=clearance)
    run = run_fleet(scene, n, "coordinated", FabricParams(), spill, EpisodeParams(max_pushes=1_000_000),
                    max_steps=steps, config=config)
    start = time.perf_counter()
    check = check_first_round(run, spill)
    pushes = check.get("pushes", [])
    return {"clearance": clearance, "rovers": n, "round": check.get("rovers", 0), "contacts": check.get("contacts"),
            "within": sum(bool(p["within"]) for p in pushes), "fraction_within": check.get("fraction_within"),
            "first_step": check.get("first_step"), "physics_s": round(time.perf_counter() - start, 1),
            "pushes": pushes}


def _markdown(result) -> str:
    lines = [f"# The fleet's concurrent pushes in physics\n\n{result['meta']}\n",
             "| clearance | rovers | pushes in the round | rover-rover contacts | within 15% | physics s |",
             "|---:|---:|---:|---:|---:|---:|"]
    for r in result["rows"]:
        lines.append(f"| {r['clearance']} | {r['rovers']} | {r['round']} | {r['contacts']} | "
                     f"{r['within']}/{r['round']} | {r['physics_s']} |")
    lines += ["", "| clearance | rover | predicted | simulated | rel. error | within |",
              "|---:|---:|---:|---:|---:|---|"]
    for r in result["rows"]:
        for p in r["pushes"]:
            err = "-" if p["relative_error"] is None else f"{p['relative_error']:.2f}"
            lines.append(f"| {r['clearance']} | {p['rover']} | {p['predicted_delivered']:.1f} | "
                         f"{p['delivered']:.0f} | {err} | {p['within']} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.fleet_physics_round",
                                     description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="example:\n  python -m experiments.fleet_physics_round --clearances 2")
    parser.add_argument("--site", default="site128", help="built-in fleet site; default site128")
    parser.add_argument("--rovers", type=int, default=4, help="fleet size; default 4")
    parser.add_argument("--clearances", type=int, nargs="+", default=[0, 1, 2], choices=(0, 1, 2))
    parser.add_argument("--steps", type=int, default=600, help="fleet steps before the check; default 600")
    parser.add_argument("--spill-model", default="learned", choices=tuple(ROVER_MODELS),
                        help="spill model the fleet plans and predicts with; default learned (LEARNED_FIT)")
    parser.add_argument("--name", default="fleet_physics_round", help="results file stem")
    args = parser.parse_args(argv)
    scene = site(args.site)
    meta = (f"{_dt.datetime.now(_dt.UTC).isoformat(timespec='seconds')}, {platform.platform()}; {args.site}, "
            f"coordinated, {args.rovers} rovers, {args.spill_model} spill model, {args.steps} fleet steps, C engine.")
    rows = []
    for clearance in args.clearances:
        rows.append(_one(scene, args.rovers, clearance, args.steps, ROVER_MODELS[args.spill_model]))
        result = {"meta": meta, "rows": rows}
        write_results(RESULTS_DIR, args.name, result, _markdown(result))


if __name__ == "__main__":
    main()
