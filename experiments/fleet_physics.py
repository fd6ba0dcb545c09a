"""Concurrent pushes in physics: 4 rovers push 4 disjoint routes at once in one MuJoCo world.

Per scene (a 64 x 64 ``random_scene(seed, layout="piles")``, or a built-in fleet site with
``--sites``): the fabric's Deliver routes of the ``--candidates`` sources with the largest J
(``bridge.plan_routes``), the first ``--rovers`` of them, best first, whose route cells dilated by one
cell do not overlap (``fleet.physics.disjoint_routes``; the fleet design's footprint rule). All the
rovers then push at once on the C engine (``fleet.physics.check_concurrent_pushes``): rover-rover
contacts, and each route's simulated delivery against the 2D prediction (``ROVER_FIT``, the spill
model fitted to this rover, as ``jaxplan rover`` uses), within 15% or not. Each route is also pushed
alone (``bridge.check_routes``, one rover per world, the same particle layout), so that what the other
rovers cost shows apart from what the 2D model misses. A scene with fewer than ``--rovers`` disjoint
routes is skipped (and listed); seeds are tried upward from ``--seed`` until ``--scenes`` are run.
``--footprint swept`` picks the routes by their swept footprints (below) instead.

The swept footprint (``route_footprint(swept=True)``: the cells the rover drives over, a fallback
route's straight run to the target and the push past the end included) is checked for the chosen
routes too: ``swept overlaps`` counts the pairs of routes whose swept footprints overlap, where
contacts are to be expected.

Results: ``experiments/results/fleet_physics.{json,md}`` (``--name`` sets the stem).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import itertools
import platform
import time
from pathlib import Path

import numpy as np

from experiments.results_io import write_results

RESULTS_DIR = Path(__file__).resolve().parent / "results"
SHAPE = (64, 64)


def _take(routes, idx):
    import jax

    return jax.tree.map(lambda a: np.asarray(a)[np.asarray(idx)], routes)


def run_scene(name: str, scene, rovers: int, candidates: int, spill, swept: bool = False) -> dict | None:
    """One scene: pick the disjoint routes, push them together and alone. None if too few routes."""
    import jax

    from jaxplan.fleet import TOLERANCE, check_concurrent_pushes, disjoint_routes, route_footprint, within_tolerance
    from jaxplan.transport.physics import check_routes, plan_routes

    t0 = time.perf_counter()
    _, routes, sources = plan_routes(scene, n_routes=candidates)
    chosen = disjoint_routes(scene, routes, rovers, swept=swept)
    plan_s = time.perf_counter() - t0
    if chosen.size < rovers:
        print(f"{name}: only {chosen.size} disjoint routes among {candidates} candidates, skipped", flush=True)
        return None
    routes = _take(routes, chosen)
    swept = [route_footprint(scene, jax.tree.map(lambda a, i=i: a[i], routes), swept=True) for i in range(rovers)]
    overlaps = [[int(a), int(b)] for a, b in itertools.combinations(range(rovers), 2) if np.any(swept[a] & swept[b])]
    t0 = time.perf_counter()
    chk = check_concurrent_pushes(scene, routes, spill=spill)
    together_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    alone = check_routes(scene, routes, spill=spill, backend="c").outcome
    alone_s = time.perf_counter() - t0
    alone_within = within_tolerance(alone.delivered, alone.predicted_delivered, TOLERANCE)
    rows = chk.rows()
    for i, row in enumerate(rows):
        row.update(source=[int(v) for v in sources[chosen[i]]], n_cells=int(np.asarray(routes.n_cells)[i]),
                   fallback=bool(np.asarray(routes.fallback)[i]), alone_delivered=float(alone.delivered[i]),
                   alone_within=bool(alone_within[i]))
    pairs = sorted({(int(a), int(b)) for _, a, b in chk.contact_events})
    summary = chk.summary() | {"contact_pairs": [list(p) for p in pairs], "swept_overlaps": overlaps,
                               "alone_fraction_within": float(np.mean(alone_within)),
                               "plan_s": plan_s, "together_s": together_s, "alone_s": alone_s}
    print(f"{name}: {rovers} rovers, contacts {chk.contacts} (pairs {pairs}), within 15%: together "
          f"{chk.fraction_within:.2f}, alone {summary['alone_fraction_within']:.2f}; physics {together_s:.0f} s "
          f"+ {alone_s:.0f} s alone", flush=True)
    return {"scene": name, "shape": list(scene.shape), "target_cells": int(np.asarray(scene.target_mask).sum()),
            "candidate_index": chosen.tolist(), "summary": summary, "routes": rows}


def _num(value, fmt: str) -> str:
    """A table cell: ``value`` formatted, or "-" for None (a non-finite number in the JSON)."""
    return "-" if value is None else format(value, fmt)


def markdown(result: dict) -> str:
    lines = ["# Concurrent pushes in physics", "",
             f"{result['date']}, {result['host']}. {result['rovers']} rovers per scene, each on one of the first "
             f"{result['rovers']} routes (best J first among {result['candidates']} sources) whose "
             + ("route cells dilated by one cell" if result.get("footprint") != "swept" else "swept footprints")
             + " are disjoint, all pushing at once in one MuJoCo world (C engine), started on their routes' "
             "starts. 'within' = simulated delivery within 15% of the 2D prediction (ROVER_FIT); 'alone' = the same "
             "route pushed by one rover in a world of its own. 'swept overlaps' = route pairs whose swept footprints "
             "(the cells the rover drives over, fallback run and push past the end included) overlap.", "",
             "| scene | target cells | contacts | touching pairs | swept overlaps | min axle gap (cells) "
             "| within (together) | within (alone) | all parked | physics s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for sc in result["scenes"]:
        s = sc["summary"]
        lines.append(f"| {sc['scene']} | {sc['target_cells']} | {s['contacts']} | {s['contact_pairs']} | "
                     f"{s['swept_overlaps']} | {_num(s['min_axle_distance_cells'], '.2f')} | "
                     f"{s['fraction_within']:.2f} | {s['alone_fraction_within']:.2f} | {s['all_reached']} | "
                     f"{s['together_s']:.0f} |")
    lines += ["", "| scene | route | source | cells | fallback | collected | predicted | delivered (together) "
              "| rel. error | within | delivered (alone) | within (alone) | spilled | left | parked at s |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for sc in result["scenes"]:
        for r in sc["routes"]:
            lines.append(f"| {sc['scene']} | {r['route']} | {tuple(r['source'])} | {r['n_cells']} | {r['fallback']} | "
                         f"{r['collected']:.0f} | {r['predicted_delivered']:.1f} | {r['delivered']:.0f} | "
                         f"{_num(r['relative_error'], '.2f')} | {r['within']} | {r['alone_delivered']:.0f} | "
                         f"{r['alone_within']} | {r['spilled']:.0f} | {r['left_behind']:.0f} | "
                         f"{_num(r['finish_time'], '.1f')} |")
    t = result["totals"]
    lines += ["", f"All scenes: {t['contacts']} rover-rover contacts (step, pair); {t['within']}/{t['pushes']} pushes "
              f"within 15% together ({_num(t['fraction_within'], '.2f')}), {t['alone_within']}/{t['pushes']} alone. "
              f"Skipped (fewer than {result['rovers']} disjoint routes): {result['skipped'] or 'none'}. "
              f"Total script time {result['total_s']:.0f} s."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.fleet_physics", description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="examples:\n  python -m experiments.fleet_physics\n"
                                        "  python -m experiments.fleet_physics --seed 3 --scenes 1 --rovers 3\n"
                                        "  python -m experiments.fleet_physics --scenes 0 --sites site128 "
                                        "--footprint swept --name fleet_physics_swept")
    ap.add_argument("--rovers", type=int, default=4, help="rovers (= disjoint routes) per scene (default 4)")
    ap.add_argument("--seed", type=int, default=0, help="first random-scene seed to try (default 0)")
    ap.add_argument("--scenes", type=int, default=2,
                    help="random 64x64 piles scenes to run (default 2; seeds without enough routes are skipped)")
    ap.add_argument("--max-seeds", type=int, default=10, help="give up after trying this many seeds (default 10)")
    ap.add_argument("--sites", nargs="*", default=[], metavar="SITE",
                    help="built-in fleet sites to run as well (site128, site256, site512; default none)")
    ap.add_argument("--candidates", type=int, default=1000,
                    help="sources (best J first) whose routes are considered (default 1000)")
    ap.add_argument("--footprint", choices=("cells", "swept"), default="cells",
                    help="disjointness rule: route cells dilated by one (default) or the swept footprint")
    ap.add_argument("--size", type=int, default=SHAPE[0], help=f"side of the random scenes (default {SHAPE[0]})")
    ap.add_argument("--name", default="fleet_physics", help="results file stem (default fleet_physics)")
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR, metavar="DIR",
                    help="where <name>.json and <name>.md go (default experiments/results)")
    args = ap.parse_args(argv)
    if args.rovers < 1 or args.scenes < 0 or args.max_seeds < 1 or args.candidates < args.rovers or args.size < 8:
        ap.error("--rovers >= 1, --scenes >= 0, --max-seeds >= 1, --candidates >= --rovers, --size >= 8")
    import jax

    import jaxplan
    from jaxplan.fleet import SITES, site
    from jaxplan.transport.spillage import ROVER_FIT

    bad = [s for s in args.sites if s not in SITES]
    if bad:
        ap.error(f"--sites: unknown {bad}; choose from {', '.join(SITES)}")
    t_start = time.perf_counter()
    swept = args.footprint == "swept"
    scenes, skipped = [], []
    for seed in range(args.seed, args.seed + args.max_seeds):
        if len(scenes) == args.scenes:
            break
        name = f"piles{args.size}_s{seed}"
        row = run_scene(name, jaxplan.random_scene(seed, (args.size, args.size), layout="piles"), args.rovers,
                        args.candidates, ROVER_FIT, swept)
        (scenes.append(row) if row else skipped.append(name))
    for name in args.sites:
        row = run_scene(name, site(name), args.rovers, args.candidates, ROVER_FIT, swept)
        (scenes.append(row) if row else skipped.append(name))
    rows = [r for sc in scenes for r in sc["routes"]]
    totals = {"contacts": int(sum(sc["summary"]["contacts"] for sc in scenes)), "pushes": len(rows),
              "within": int(sum(r["within"] for r in rows)), "alone_within": int(sum(r["alone_within"] for r in rows)),
              "fraction_within": float(np.mean([r["within"] for r in rows])) if rows else None}
    result = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "host": platform.platform(),
              "jax": jax.__version__, "rovers": args.rovers, "candidates": args.candidates, "footprint": args.footprint,
              "spill": "ROVER_FIT",
              "tolerance": 0.15, "scenes": scenes, "skipped": skipped, "totals": totals,
              "total_s": time.perf_counter() - t_start}
    write_results(args.results_dir, args.name, result, markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
