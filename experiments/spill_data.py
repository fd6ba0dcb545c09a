"""Routes and what the MuJoCo rover did with them: a data set to fit spill models to physics.

Scenes of four families (``FAMILIES``: uniform counts, speckled single objects, gaussian piles,
dense strips), each at several densities, on one grid shape. On each scene the fabric plans the
routes of the ``--sources`` sources with the largest J (table entry 0, the selected route) and
their alternatives (entries 1 .. ``--entries`` - 1: other turn profiles from the same source); each
route (and, with ``--perturbed K``, K copies of it with one interior cell moved: ``perturb_route``)
is pushed by the rover on the C engine (``transport.physics.check_routes``, batched) under
``--layouts`` particle layouts. A record holds one route under one layout: the per-cell counts
before, the route's cells, the counts after (the particles rasterised back to the grid,
``bridge.projected_obj``), and the rover's verdicts (collected, delivered, left behind, spilled,
lost; lateral error; whether it stayed finite and reached the end), beside ``ROVER_FIT``'s
prediction of the same route, so any model can be fitted to it.

The split is by scene, never by route: the scenes of every ``HOLDOUT``-th seed are held out, so
every family and density has held-out scenes. The default configuration makes 20 seeds x 4 families
x 3 densities = 240 scenes of 20 x 20 cells, up to 8 routes each (4 sources x 2 entries, fewer where
a source has no alternative): 180 training and 60 held-out scenes (seeds 3, 7, 11, 15, 19), sized
for at least 1,000 training and 300 held-out routes, each under 2 layouts. It is regenerable from
the script and its arguments: the scenes, routes and layouts are seeded. Writes ``OUT.npz``
(compressed, written to a temporary file and renamed, so an interrupted run leaves no half file) and
``OUT.json`` (the manifest: arguments, counts per split, family and density, the archive's SHA-256).

    python -m experiments.spill_data --out experiments/data/spill             # the full set
    python -m experiments.spill_data --perturbed 1 --only-perturbed --out experiments/data/spill_perturbed
    python -m experiments.spill_data --quick --out /tmp/spill_quick             # 8 scenes, a smoke test
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

FAMILIES = ("uniform", "speckled", "piles", "strips")
DENSITIES = (0.15, 0.35, 0.6)
HOLDOUT = 4
SHAPE = (20, 20)
MAX_COUNT = 6


def family_scene(family: str, density: float, seed: int, shape=SHAPE):
    """One scene of ``family`` at ``density`` (the share of cells holding material; for strips, the
    share of rows that are strips), seeded; a round target near one side, no material on it."""
    from jaxplan.transport import Scene, circle, random_scene

    h, w = shape
    rng = np.random.default_rng([seed, FAMILIES.index(family), int(round(density * 1000)), h, w])
    if family == "piles":
        return random_scene(seed, shape, density, layout="piles", max_count=MAX_COUNT)
    if family == "uniform":
        obj = np.where(rng.random(shape) < density, rng.integers(1, MAX_COUNT + 1, shape), 0)
    elif family == "speckled":
        obj = (rng.random(shape) < density).astype(int)
    else:
        obj = np.zeros(shape, int)
        rows = rng.random(h) < density
        obj[rows] = rng.integers(3, MAX_COUNT + 1, (int(rows.sum()), w))
        if rng.random() < 0.5:
            obj = obj.T.copy()
    side = rng.integers(4)
    centre = [(w / 2, 2.5), (w / 2, h - 2.5), (2.5, h / 2), (w - 2.5, h / 2)][side]
    scene = Scene.from_arrays(np.zeros(shape), circle(centre, 2.2), name=f"{family}_d{density:g}_s{seed}")
    return scene.with_obj(np.where(np.asarray(scene.target_mask), 0.0, obj).astype(np.float32))


def perturb_route(scene, cells, rng):
    """A copy of the walk ``cells: i[n, 2]`` with one interior cell moved to another free cell that
    neighbours both of its neighbours (8-connected, in the grid, not blocked, not a target, not on
    the walk), chosen by ``rng``; None when no interior cell has such a neighbour. The walk keeps
    its source and its end, so it collects and delivers as a route does, along another shape."""
    h, w = scene.shape
    cells = np.asarray(cells)
    blocked = np.asarray(scene.blocked) | np.asarray(scene.target_mask)
    on_walk = {tuple(c) for c in cells.tolist()}
    for i in rng.permutation(np.arange(1, len(cells) - 1)):
        (r0, c0), (r1, c1) = cells[i - 1], cells[i + 1]
        rows, cols = range(max(r0, r1) - 1, min(r0, r1) + 2), range(max(c0, c1) - 1, min(c0, c1) + 2)
        options = [(r, c) for r in rows for c in cols
                   if 0 <= r < h and 0 <= c < w and not blocked[r, c] and (r, c) not in on_walk]
        if options:
            out = cells.copy()
            out[i] = options[rng.integers(len(options))]
            return out
    return None


def scene_routes(scene, sources: int, entries: int, perturbed: int = 0, planned: bool = True):
    """``(routes: execute.Route [B], source i32[B, 2], entry i32[B], perturbed i32[B])``: the
    ``sources`` sources with the largest J, each with table entries 0 .. ``entries`` - 1 that exist
    and leave the source, then ``perturbed`` perturbations of each (``perturb_route``, seeded by the
    scene's name; ``perturbed`` = k for the k-th, 0 for the planned routes). ``planned=False`` keeps
    only the perturbations (the same ones a run with both makes)."""
    import zlib

    import jax

    from jaxplan.transport import FabricParams, build_fabric, extract_paths, route_from_path, routes_from_paths

    fabric = build_fabric(scene, FabricParams())
    value = np.where(np.asarray(fabric.occupied), np.asarray(fabric.value), -np.inf)
    order = np.argsort(-value, axis=None, kind="stable")[:sources]
    order = order[np.isfinite(value.reshape(-1)[order])]
    w = scene.shape[1]
    src = np.repeat(np.stack([order // w, order % w], -1), entries, 0).astype(np.int32)
    rank = np.tile(np.arange(entries, dtype=np.int32), len(order))
    paths = extract_paths(fabric, src, rank, detour=scene.detour)
    keep = np.isfinite(np.asarray(paths.raw)) & (np.asarray(paths.n_cells) >= 2)
    paths = jax.tree.map(lambda a: np.asarray(a)[keep], paths)
    routes = jax.tree.map(np.asarray, routes_from_paths(scene, paths))
    src, rank = src[keep], rank[keep]
    variant = np.zeros(len(rank), np.int32)
    rng = np.random.default_rng(zlib.crc32((scene.name or "").encode()))
    extra = []
    for k in range(1, perturbed + 1):
        for i in range(len(rank)):
            n = int(routes.n_cells[i])
            moved = perturb_route(scene, routes.cells[i][:n], rng)
            if moved is not None:
                cells = routes.cells[i].copy()
                cells[:n] = moved
                extra.append((route_from_path(scene, cells, n, routes.fallback[i]), src[i], rank[i], k))
    if extra:
        more = jax.tree.map(lambda *a: np.stack([np.asarray(x) for x in a]), *[e[0] for e in extra])
        routes = jax.tree.map(lambda a, b: np.concatenate([a, b]), routes, more)
        src = np.concatenate([src, np.stack([e[1] for e in extra])])
        rank = np.concatenate([rank, np.asarray([e[2] for e in extra], np.int32)])
        variant = np.concatenate([variant, np.asarray([e[3] for e in extra], np.int32)])
    if not planned:
        keep = variant > 0
        routes = jax.tree.map(lambda a: a[keep], routes)
        src, rank, variant = src[keep], rank[keep], variant[keep]
    return routes, src, rank, variant


def scene_records(scene, sources: int, entries: int, layouts: int, backend: str = "auto",
                  perturbed: int = 0, planned: bool = True) -> list[dict]:
    """Every route of ``scene_routes`` under ``layouts`` particle layouts, pushed in one batch."""
    import jax

    from jaxplan.transport.physics import check_routes, projected_obj
    from jaxplan.transport.spillage import ROVER_FIT

    routes, src, rank, variant = scene_routes(scene, sources, entries, perturbed, planned)
    n = int(np.asarray(routes.n_cells).shape[0])
    if n == 0:
        return []
    # route i under layout l sits at batch position l * n + i; a layout is seeded by its position
    batch = jax.tree.map(lambda a: np.concatenate([np.asarray(a)] * layouts), routes)
    check = check_routes(scene, batch, spill=ROVER_FIT, backend=backend)
    out = check.outcome
    before = np.asarray(scene.obj, np.float32)
    records = []
    for j in range(n * layouts):
        i = j % n
        after, lost = projected_obj(scene, check, j)
        cells = np.asarray(routes.cells[i])[: int(routes.n_cells[i])]
        records.append({
            "obj_before": before, "obj_after": np.asarray(after, np.float32), "cells": cells.astype(np.int16),
            "source": src[i], "entry": int(rank[i]), "perturbed": int(variant[i]), "layout": j // n,
            **{k: float(np.asarray(getattr(out, k))[j]) for k in
               ("collected", "delivered", "left_behind", "spilled", "lost", "predicted_delivered",
                "predicted_spilled", "mean_lateral")},
            "finite": bool(np.asarray(out.finite)[j]), "reached": bool(np.asarray(out.reached)[j]),
        })
    return records


def is_heldout(seed: int) -> bool:
    """Whether the scenes of ``seed`` are held out: every ``HOLDOUT``-th seed, all its families and
    densities."""
    return seed % HOLDOUT == HOLDOUT - 1


def _plan(seeds, densities) -> list[tuple[str, float, int]]:
    return [(f, d, s) for s in seeds for f in FAMILIES for d in densities]


def _stack(records: list[dict], scene_meta: list[dict]) -> dict:
    """The records as arrays: cells padded with -1 to the longest route."""
    longest = max(len(r["cells"]) for r in records)
    cells = np.full((len(records), longest, 2), -1, np.int16)
    for k, r in enumerate(records):
        cells[k, : len(r["cells"])] = r["cells"]
    arrays = {"cells": cells, "n_cells": np.asarray([len(r["cells"]) for r in records], np.int32),
              "obj_before": np.stack([r["obj_before"] for r in records]),
              "obj_after": np.stack([r["obj_after"] for r in records]),
              "source": np.stack([r["source"] for r in records]).astype(np.int16)}
    for key in ("entry", "perturbed", "layout", "scene"):
        arrays[key] = np.asarray([r[key] for r in records], np.int32)
    for key in ("collected", "delivered", "left_behind", "spilled", "lost", "predicted_delivered",
                "predicted_spilled", "mean_lateral"):
        arrays[key] = np.asarray([r[key] for r in records], np.float32)
    for key in ("finite", "reached"):
        arrays[key] = np.asarray([r[key] for r in records], bool)
    arrays["scene_family"] = np.asarray([m["family"] for m in scene_meta])
    arrays["scene_density"] = np.asarray([m["density"] for m in scene_meta], np.float32)
    arrays["scene_seed"] = np.asarray([m["seed"] for m in scene_meta], np.int32)
    arrays["scene_heldout"] = np.asarray([m["heldout"] for m in scene_meta], bool)
    arrays["scene_target_mask"] = np.stack([m["target_mask"] for m in scene_meta])
    return arrays


def _counts(records, scene_meta) -> dict:
    counts: dict = {"train": {"routes": 0, "records": 0}, "heldout": {"routes": 0, "records": 0}}
    for r in records:
        meta = scene_meta[r["scene"]]
        split = counts["heldout" if meta["heldout"] else "train"]
        split["records"] += 1
        split["routes"] += int(r["layout"] == 0)
        key = f"{meta['family']} d{meta['density']:g}"
        split[key] = split.get(key, 0) + int(r["layout"] == 0)
    return counts


def write_atomically(path: Path, arrays: dict) -> str:
    """``np.savez_compressed`` to a temporary file renamed over ``path``; the archive's SHA-256."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    os.replace(tmp, path)
    return hashlib.sha256(path.read_bytes()).hexdigest()


def generate(seeds, densities, sources: int, entries: int, layouts: int, progress: bool = True,
             backend: str = "auto", perturbed: int = 0, planned: bool = True):
    """``(records, scene_meta)`` for every (family, density, seed) of the plan, in order."""
    from tqdm.auto import tqdm

    records, scene_meta = [], []
    for k, (family, density, seed) in enumerate(tqdm(_plan(seeds, densities), desc="scenes", disable=not progress)):
        scene = family_scene(family, density, seed)
        scene_meta.append({"family": family, "density": density, "seed": seed, "heldout": is_heldout(seed),
                           "target_mask": np.asarray(scene.target_mask)})
        for r in scene_records(scene, sources, entries, layouts, backend, perturbed, planned):
            records.append({**r, "scene": k})
    return records, scene_meta


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m experiments.spill_data", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="examples:\n"
                                            "  python -m experiments.spill_data --out experiments/data/spill\n"
                                            "  python -m experiments.spill_data --quick --out /tmp/spill_quick")
    parser.add_argument("--out", required=True, help="output stem: writes OUT.npz and OUT.json")
    parser.add_argument("--seeds", type=int, default=20, help="seeds per family and density; default 20")
    parser.add_argument("--sources", type=int, default=4, help="sources per scene (largest J); default 4")
    parser.add_argument("--entries", type=int, default=2, help="table entries per source (routes); default 2")
    parser.add_argument("--layouts", type=int, default=2, help="particle layouts per route; default 2")
    parser.add_argument("--perturbed", type=int, default=0,
                        help="perturbed copies of each planned route (one interior cell moved); default 0")
    parser.add_argument("--only-perturbed", action="store_true",
                        help="write only the perturbed copies (a second archive beside a set of planned routes)")
    parser.add_argument("--backend", default="auto", choices=("auto", "c", "mjx", "warp"),
                        help="physics engine; default auto (the C engine on a CPU, MJX-Warp on a GPU with warp-lang)")
    parser.add_argument("--quick", action="store_true",
                        help="two seeds (one held out), a scene per family each, two routes, one layout (a smoke "
                             "test)")
    args = parser.parse_args(argv)
    for name in ("seeds", "sources", "entries", "layouts"):
        if getattr(args, name) < 1:
            parser.error(f"--{name}: {getattr(args, name)} is not a count; give an int >= 1.")
    if args.perturbed < 0:
        parser.error(f"--perturbed: {args.perturbed} is not a count; give an int >= 0.")
    if args.only_perturbed and args.perturbed == 0:
        parser.error("--only-perturbed with --perturbed 0 writes nothing; give --perturbed 1 or more.")
    seeds, densities = range(args.seeds), DENSITIES
    if args.quick:
        args.seeds, args.sources, args.entries, args.layouts = HOLDOUT, 2, 1, 1
        seeds, densities = (0, HOLDOUT - 1), (0.35,)        # one training and one held-out seed
    start = time.perf_counter()
    records, scene_meta = generate(seeds, densities, args.sources, args.entries, args.layouts,
                                   backend=args.backend, perturbed=args.perturbed, planned=not args.only_perturbed)
    if not records:
        parser.error("no route was planned on any scene; nothing to write.")
    out = Path(args.out)
    digest = write_atomically(out.with_suffix(".npz"), _stack(records, scene_meta))
    manifest = {"command": "python -m experiments.spill_data " + " ".join(sys.argv[1:] if argv is None else argv),
                "arguments": {k: v for k, v in vars(args).items() if k != "out"}, "shape": list(SHAPE),
                "families": list(FAMILIES), "densities": list(densities), "holdout_every": HOLDOUT,
                "scenes": len(scene_meta), "counts": _counts(records, scene_meta),
                "npz": out.with_suffix(".npz").name, "sha256": digest, "seconds": round(time.perf_counter() - start, 1)}
    out.with_suffix(".json").write_text(json.dumps(manifest, indent=1) + "\n")
    print(f"wrote {out.with_suffix('.npz')} ({len(records)} records, {len(scene_meta)} scenes) and "
          f"{out.with_suffix('.json')}")
    return manifest


if __name__ == "__main__":
    main()
