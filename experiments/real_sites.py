"""Sites with buildings from a public benchmark map: the fabric, an episode and a fleet on them.

The map is ``random-32-32-20`` of the MovingAI grid-based MAPF benchmarks (Sturtevant, "Benchmarks for
Grid-Based Pathfinding", https://movingai.com/benchmarks/mapf/index.html; the copy in
``experiments/maps/`` is the one distributed with https://github.com/ghostwwb/LNS2). Each map cell is
drawn at ``--scales`` grid cells a side (a building of one map cell covers scale x scale cells), and
``site_from_map`` places two targets and piles of material on free cells from each seed.

Per site it measures, in one process:

- the site's geometry: blocked cells, cells on a detour, material cut off from every target;
- a warm ``build_fabric`` on the site against the same counts and targets without the blocked cells
  (ratio measured side by side);
- ``run_episode`` to its stop: pushes, delivered share of the reachable mass, whether material ever
  lies on a blocked cell;
- ``run_fleet`` with ``--rovers`` coordinated rovers: steps, T50 / T90, conflicts, rover-steps on a
  blocked cell.

    python -m experiments.real_sites                       # scales 1, 2, 4; seeds 0-2; 4 rovers
    python -m experiments.real_sites --scales 1 --seeds 0 --rovers 2 --name real_sites_quick
"""
from __future__ import annotations

import argparse
import datetime as _dt
import platform
import statistics
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from experiments.results_io import write_results
from jaxplan import FabricParams, Scene, SpillParams, build_fabric, run_episode
from jaxplan.fleet import run_fleet, summary_of
from jaxplan.transport import EpisodeParams, read_movingai_map, site_from_map

RESULTS_DIR = Path(__file__).resolve().parent / "results"
MAP = Path(__file__).resolve().parent / "maps" / "random-32-32-20.map"


def scaled_map(path: Path, scale: int, out_dir: Path) -> Path:
    """A copy of the map with every cell drawn ``scale`` x ``scale`` (MovingAI format, rows as the file)."""
    blocked = np.kron(read_movingai_map(path)[::-1], np.ones((scale, scale), bool))
    h, w = blocked.shape
    lines = ["type octile", f"height {h}", f"width {w}", "map"] + ["".join("@" if b else "." for b in row)
                                                                    for row in blocked]
    out = out_dir / f"{path.stem}-x{scale}.map"
    out.write_text("\n".join(lines) + "\n")
    return out


def _warm_ms(fn, repeats: int = 5) -> float:
    jax.block_until_ready(fn())
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        runs.append(1e3 * (time.perf_counter() - start))
    return statistics.median(runs)


def measure(site: Scene, rovers: int, max_steps: int) -> dict:
    params, spill = FabricParams(), SpillParams(lam=0.05)
    blocked = np.asarray(site.blocked)
    open_site = Scene.from_arrays(site.obj, site.target)
    start = time.perf_counter()
    Scene.from_arrays(site.obj, site.target, blocked=blocked)
    geometry_ms = 1e3 * (time.perf_counter() - start)
    build_ms = _warm_ms(lambda: build_fabric(site, params))
    open_ms = _warm_ms(lambda: build_fabric(open_site, params))
    episode = run_episode(site, params, spill, EpisodeParams(max_pushes=400))
    totals = episode.totals()
    reachable = totals["initial_remaining"] - totals["unreachable_mass"]
    fleet = run_fleet(site, rovers, "coordinated", params, spill, EpisodeParams(max_pushes=100_000),
                      max_steps=max_steps)
    s = summary_of(fleet)
    return dict(
        shape=list(site.shape), blocked_cells=int(blocked.sum()),
        detour_cells=int((np.asarray(site.detour) >= 0).sum()),
        mass=float(site.total_mass), unreachable_mass=float(site.unreachable_mass), geometry_ms=geometry_ms,
        build_ms=build_ms, open_build_ms=open_ms, build_ratio=build_ms / open_ms,
        episode_stop=episode.stop_reason, episode_pushes=episode.n_pushes,
        episode_delivered_share=totals["delivered"] / reachable if reachable > 0 else None,
        episode_material_on_blocked=float(np.asarray(episode.final_obj)[blocked].sum()),
        fleet_rovers=rovers, fleet_steps=s["steps"], fleet_T50=s["T50"], fleet_T90=s["T90"],
        fleet_conflicts=s["conflicts"], fleet_stop=s["stop_reason"],
        fleet_rover_steps_on_blocked=int(blocked[fleet.pos[..., 0], fleet.pos[..., 1]].sum()),
        fleet_material_on_blocked=float(np.asarray(fleet.final_scene.obj)[blocked].sum()))


def _table(rows) -> str:
    head = ("| site | grid | blocked | on a detour | cut off (objects) | build ms (open) | ratio | episode: stop, "
            "pushes, delivered | fleet: N, steps, T50, T90, conflicts | on blocked (rover-steps, objects) |")
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        share = "-" if r["episode_delivered_share"] is None else f"{100 * r['episode_delivered_share']:.0f}%"
        lines.append(
            f"| {r['site']} | {r['shape'][0]}x{r['shape'][1]} | {r['blocked_cells']} | {r['detour_cells']} | "
            f"{r['unreachable_mass']:.0f} | {r['build_ms']:.1f} ({r['open_build_ms']:.1f}) | {r['build_ratio']:.2f} | "
            f"{r['episode_stop']}, {r['episode_pushes']}, {share} | {r['fleet_rovers']}, {r['fleet_steps']}, "
            f"{r['fleet_T50']}, {r['fleet_T90']}, {r['fleet_conflicts']} | {r['fleet_rover_steps_on_blocked']}, "
            f"{r['episode_material_on_blocked'] + r['fleet_material_on_blocked']:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0], epilog="example: python -m "
                                     "experiments.real_sites --scales 1 2 --seeds 0 1 --rovers 4",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scales", type=int, nargs="+", default=[1, 2, 4], help="grid cells per map cell")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="site seeds (targets, piles)")
    parser.add_argument("--rovers", type=int, default=4, help="coordinated rovers in the fleet run")
    parser.add_argument("--max-steps", type=int, default=20_000, help="fleet step limit")
    parser.add_argument("--name", default="real_sites", help="results stem")
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for scale in args.scales:
            path = scaled_map(MAP, scale, Path(tmp))
            for seed in args.seeds:
                site = site_from_map(path, seed, n_targets=2)
                row = dict(site=f"{MAP.stem} x{scale}, seed {seed}", **measure(site, args.rovers, args.max_steps))
                rows.append(row)
                print(row, flush=True)
    result = dict(rows=rows, map=str(MAP.name), map_source="https://movingai.com/benchmarks/mapf/index.html",
                  date=_dt.date.today().isoformat(), machine=platform.platform(), cpus=jax.local_device_count(),
                  backend=jax.default_backend())
    markdown = (f"# Sites from a benchmark map ({MAP.name}, MovingAI)\n\n" + _table(rows) +
                "\nbuild ms: warm `build_fabric` with the blocked cells, and (in brackets) on the same counts "
                "and targets without them; ratio = the two, measured side by side. delivered: share of the "
                "mass a target can be reached from.\n")
    write_results(args.results_dir, args.name, result, markdown)


if __name__ == "__main__":
    main()
