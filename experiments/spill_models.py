"""Spill models against MuJoCo on held-out scenes: curvature, capacity, ``ROVER_FIT`` and learned.

Reads a data set of ``experiments/spill_data.py`` (routes pushed by the rover on the C engine), fits
on its training scenes, and scores every model on the same held-out routes (scenes never seen in a
fit; the split is the data set's, by scene):

- ``curvature``: the paper's model, ``lam`` and ``threshold`` fitted (``jaxplan.tune.fit_spill``);
- ``capacity``: the capacity-aware model refitted (``fit_capacity``: capacity, lam, mu, turn
  saturation, and ``miss`` from the mass left behind);
- ``ROVER_FIT``: the capacity model's fit to the four built-in scenes, as shipped;
- ``learned``: the learned model (``jaxplan.tune.fit_learned``).

A route's physical delivered mass is the mean over its particle layouts (the layouts of one route
differ by a few percent; the model predicts the route, not the layout). Scored per density class and
family: the share of routes predicted within 10% of physics, the median relative error, and the
mean delivered, spilled and left-behind mass of physics beside the model's delivered and lost
(spilled + left behind) mass. Writes ``experiments/results/spill_models.{json,md}``; with
``--write-fit`` also the learned parameters to ``jaxplan/transport/spillage/learned_fit.json`` (what
``LEARNED_FIT`` loads).

    python -m experiments.spill_models                          # experiments/data/spill.npz
    python -m experiments.spill_models --data experiments/data/spill.npz --write-fit
"""
from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import jax
import numpy as np

from experiments.results_io import write_results
from experiments.spill_data import HOLDOUT, family_scene

DEFAULT_DATA = (Path("experiments/data/spill.npz"), Path("experiments/data/spill_perturbed.npz"))
HIDDEN = (4, 8, 16)
FIT_FILE = Path("jaxplan/transport/spillage/learned_fit.json")
WITHIN = 0.10


@jax.jit
def _route_inputs(scene, cells, n_cells, fallback):
    """``(waypoints f32[B, S+1, 2], n_points i32[B], pickup f32[B, S+1])`` of B routes on one scene."""
    from jaxplan.transport import route_from_path, waypoint_pickup, waypoints

    def one(c, n, f):
        route = route_from_path(scene, c, n, f)
        points, n_points = waypoints(scene, route)
        return points, n_points, waypoint_pickup(scene, route)[0]

    return jax.vmap(one)(cells, n_cells, fallback)


def read_archives(paths) -> dict:
    """The records of one or more archives of ``experiments/spill_data.py`` made on the same scenes
    (e.g. the planned routes and their ``--only-perturbed`` copies), concatenated."""
    parts = [dict(np.load(p)) for p in paths]
    for d in parts:                     # archives made before --perturbed hold planned routes only
        d.setdefault("perturbed", np.zeros_like(d["entry"]))
    first = parts[0]
    for path, d in zip(paths[1:], parts[1:]):
        same = d.keys() == first.keys() and all(np.array_equal(d[k], first[k]) for k in first if k.startswith("scene_"))
        if not same:
            raise ValueError(f"{path}: its scenes differ from {paths[0]}'s; give archives made with the same "
                             "--seeds (and the same version of experiments/spill_data.py).")
    out = dict(first)
    for k in first:
        if not k.startswith("scene_"):
            width = max(d[k].shape[1] for d in parts) if k == "cells" else None
            out[k] = np.concatenate([_pad_cells(d[k], width) if width else d[k] for d in parts])
    return out


def _pad_cells(cells, width):
    return np.concatenate([cells, np.full((len(cells), width - cells.shape[1], 2), -1, cells.dtype)], 1)


def load_routes(paths, seeds: int | None = None) -> dict:
    """The data set's records as model inputs: ``data`` (a ``tune.SpillData`` over records, delivered
    and spilled as physics measured them: spilled = collected - delivered), per-record arrays
    (``heldout``, ``seed``, ``family``, ``density``, ``perturbed``, ``route``: an id shared by a
    route's layouts), and the physics outcomes. ``paths``: one archive or several on the same scenes.
    Scenes are rebuilt from their family, density and seed. ``seeds``: keep only the scenes of seeds
    below it (a quick run)."""
    from jaxplan.tune import SpillData

    paths = [Path(paths)] if isinstance(paths, (str, Path)) else [Path(p) for p in paths]
    d = read_archives(paths)
    if seeds is not None:
        keep = d["scene_seed"][d["scene"]] < seeds
        d = {k: (v[keep] if not k.startswith("scene_") else v) for k, v in d.items()}
    cells = d["cells"].astype(np.int32)
    n_cells = d["n_cells"]
    last = cells[np.arange(len(n_cells)), n_cells - 1]
    scene_of = d["scene"]
    fallback = ~d["scene_target_mask"][scene_of, last[:, 0], last[:, 1]]
    s = cells.shape[1] + 1
    way, npt, pick = np.zeros((len(n_cells), s, 2), np.float32), np.zeros(len(n_cells), np.int32), np.zeros(
        (len(n_cells), s), np.float32)
    for k in np.unique(scene_of):
        rows = np.where(scene_of == k)[0]
        scene = family_scene(str(d["scene_family"][k]), float(d["scene_density"][k]), int(d["scene_seed"][k]))
        w, n, p = _route_inputs(scene, cells[rows], n_cells[rows], fallback[rows])
        way[rows], npt[rows], pick[rows] = np.asarray(w), np.asarray(n), np.asarray(p)
    if not np.allclose(pick.sum(1), d["collected"]):
        raise ValueError(f"{', '.join(map(str, paths))}: the rebuilt routes collect other masses than the data "
                         "set records; was it written by another version of experiments/spill_data.py?")
    perturbed = d["perturbed"]
    key = np.stack([scene_of, d["source"][:, 0], d["source"][:, 1], d["entry"], perturbed], 1)
    _, route = np.unique(key, axis=0, return_inverse=True)
    delivered = d["delivered"].astype(np.float32)
    return {"data": SpillData(way, npt, pick, delivered, d["collected"] - delivered),
            "heldout": d["scene_heldout"][scene_of], "seed": d["scene_seed"][scene_of],
            "family": d["scene_family"][scene_of], "density": d["scene_density"][scene_of],
            "perturbed": perturbed > 0, "route": route.reshape(-1),
            "collected": d["collected"], "delivered": delivered, "spilled": d["spilled"],
            "left_behind": d["left_behind"], "lost": d["lost"]}


def _subset(data, rows):
    return type(data)(*(np.asarray(x)[rows] for x in data))


def validation_rows(routes: dict) -> np.ndarray:
    """Training records set aside to choose the network's size: the scenes of every ``HOLDOUT``-th
    training seed (1, 5, 9, ...), never the held-out ones."""
    return ~routes["heldout"] & (routes["seed"] % HOLDOUT == 1)


def choose_hidden(routes: dict, sizes, steps: int, progress: bool) -> tuple[int, dict]:
    """The hidden size among ``sizes`` whose fit on the training scenes less the validation scenes
    predicts the most planned validation routes within 10%; and each size's share."""
    from jaxplan import tune

    val = validation_rows(routes)
    fit_on = _subset(routes["data"], np.where(~routes["heldout"] & ~val)[0])
    shares = {}
    for h in sizes:
        params = tune.fit_learned(fit_on, hidden=int(h), steps=steps, progress=progress).params
        shares[int(h)] = within_share(routes, params, val & ~routes["perturbed"])
    return max(shares, key=lambda h: (shares[h], -h)), shares


def within_share(routes: dict, params, rows) -> float:
    """The share of the routes of ``rows`` (records) whose predicted delivered mass lies within 10% of
    physics' (the mean over the route's layouts)."""
    from jaxplan.tune import predict_spill

    route = routes["route"][rows]
    ids, first = np.unique(route, return_index=True)
    physics = np.bincount(route, routes["delivered"][rows].astype(np.float64))[ids] / np.bincount(route)[ids]
    predicted, _ = jax.jit(predict_spill)(params, _subset(routes["data"], np.where(rows)[0][first]))
    rel = np.abs(np.asarray(predicted, np.float64) - physics) / np.maximum(physics, 1e-9)
    return round(float(np.mean(rel <= WITHIN)), 3)


def fit_models(routes: dict, steps: int, progress: bool, quick: bool = False, hidden=(8,)) -> dict:
    """Every model of the comparison, fitted on the training records (``quick``: a few steps each, a
    coarse capacity grid and a coarse ``miss`` search, a smoke test); the learned model's hidden size
    chosen on validation scenes of the training seeds when ``hidden`` offers more than one
    (``choose_hidden``)."""
    from jaxplan import tune
    from jaxplan.transport.spillage import FIT_GRID, ROVER_FIT, CapacitySpillParams, SpillParams, fit_capacity, fit_miss

    train = np.where(~routes["heldout"])[0]
    data = _subset(routes["data"], train)
    fit_steps = {"steps": 20, "polish_steps": 5} if quick else {}
    curvature = tune.fit_spill(data, SpillParams(lam=0.05, threshold=0.1, temperature=0.01), **fit_steps).params
    grid = {k: v[::3] for k, v in FIT_GRID.items()} if quick else None
    left_behind, base = routes["left_behind"][train], None
    if quick:   # miss searched in steps of 0.01 (fit_capacity's own search: 5e-4, 20x the candidates), then held
        base = CapacitySpillParams()
        base = base.replace(miss=fit_miss(data.waypoints, data.n_points, data.pickup, left_behind,
                                          samples_per_step=base.samples_per_step, spline_alpha=base.spline_alpha,
                                          resolution=0.01))
        left_behind = None
    capacity = fit_capacity(data.waypoints, data.n_points, data.pickup, data.delivered,
                            fields=("capacity", "lam", "mu", "turn_saturation"), grid=grid,
                            steps=20 if quick else 300, left_behind=left_behind, base=base).params
    size, shares = (int(hidden[0]), {}) if len(hidden) == 1 else choose_hidden(routes, hidden, steps, progress)
    learned = tune.fit_learned(data, hidden=size, steps=steps, progress=progress)
    return {"curvature": curvature, "capacity": capacity, "ROVER_FIT": ROVER_FIT, "learned": learned.params,
            "_learned_losses": learned.losses, "_hidden": size, "_validation": shares}


def _per_route(values, route):
    """Mean of ``values`` over each route's records, indexed by route id."""
    return np.bincount(route, values) / np.bincount(route)


def score(routes: dict, models: dict) -> dict:
    """Per split, per density class and family of the planned routes, and the perturbed routes as one
    class: within-10% share, median relative error and masses."""
    from jaxplan.tune import predict_spill

    route = routes["route"]
    first = np.unique(route, return_index=True)[1]           # one record per route: its inputs
    inputs = _subset(routes["data"], first)
    physics = {k: _per_route(routes[k].astype(np.float64), route) for k in
               ("collected", "delivered", "spilled", "left_behind", "lost")}
    # how far a route's layouts lie apart: (max - min) / mean of its delivered mass
    by_route = routes["delivered"].astype(np.float64)[np.argsort(route, kind="stable")]
    starts = np.unique(np.sort(route), return_index=True)[1]
    spread = np.maximum.reduceat(by_route, starts) - np.minimum.reduceat(by_route, starts)
    physics["layout_spread"] = spread / np.maximum(physics["delivered"], 1e-9)
    groups = {"heldout": routes["heldout"][first], "family": routes["family"][first],
              "density": routes["density"][first], "perturbed": routes["perturbed"][first]}
    predicted = {}
    for name, params in models.items():
        if name.startswith("_"):
            continue
        delivered, _ = jax.jit(predict_spill)(params, inputs)
        predicted[name] = np.asarray(delivered, np.float64)
    out = {}
    for split, scenes in (("heldout", groups["heldout"]), ("train", ~groups["heldout"])):
        in_split = scenes & ~groups["perturbed"]             # the classes count planned routes
        classes = {"all": in_split}
        for density in np.unique(groups["density"]):
            classes[f"density {density:g}"] = in_split & np.isclose(groups["density"], density)
        for family in np.unique(groups["family"]):
            classes[str(family)] = in_split & (groups["family"] == family)
        if groups["perturbed"].any():
            classes["perturbed routes"] = scenes & groups["perturbed"]
        out[split] = {cls: _class_row(mask, physics, predicted) for cls, mask in classes.items()}
    return out


def _class_row(mask, physics, predicted) -> dict:
    obs = physics["delivered"][mask]
    row = {"routes": int(mask.sum()),
           "physics": {k: round(float(v[mask].mean()), 2) for k, v in physics.items() if k != "layout_spread"},
           "models": {}}
    row["physics"]["layout_spread_median"] = round(float(np.median(physics["layout_spread"][mask])), 3)
    for name, pred in predicted.items():
        p = pred[mask]
        rel = np.abs(p - obs) / np.maximum(obs, 1e-9)
        row["models"][name] = {"within_10pct": round(float(np.mean(rel <= WITHIN)), 3),
                               "median_rel_error": round(float(np.median(rel)), 3),
                               "delivered": round(float(p.mean()), 2),
                               "lost": round(float((physics["collected"][mask] - p).mean()), 2)}
    return row


def build_cost(models: dict, shape=(48, 48), repeats: int = 5, only=None) -> dict:
    """Median seconds of a full build with Eq. 6 (``build_fabric`` then ``selection.reselect`` of every
    source with the model) per model, measured side by side on one piles scene after a warm-up, and
    each model's ratio to ``ROVER_FIT``'s (``only``: the names to measure; default every model)."""
    from jaxplan.transport import FabricParams, build_fabric, default_walk_cap, random_scene, reselect
    from jaxplan.transport.spillage import evaluator_for

    scene = random_scene(0, shape, 0.5, layout="piles")
    params = FabricParams()
    cap = default_walk_cap(shape)

    def build(spill):
        fabric = build_fabric(scene, params)
        fabric = reselect(scene, params, fabric, spill, max_steps=cap, evaluator=evaluator_for(spill))
        jax.block_until_ready(fabric.selected)

    times = {name: [] for name in models if not name.startswith("_") and (only is None or name in only)}
    for name in times:
        build(models[name])                     # compile
    for _ in range(repeats):                    # interleaved: the models share the machine's state
        for name in times:
            t = time.perf_counter()
            build(models[name])
            times[name].append(time.perf_counter() - t)
    med = {name: float(np.median(v)) for name, v in times.items()}
    return {"shape": list(shape), "repeats": repeats, "seconds": {k: round(v, 4) for k, v in med.items()},
            "ratio_to_ROVER_FIT": {k: round(v / med["ROVER_FIT"], 3) for k, v in med.items()}}


def learned_to_json(params) -> dict:
    return {name: np.asarray(getattr(params, name), np.float64).round(6).tolist()
            for name in ("w1", "b1", "w2", "b2", "load_w")}


def markdown(result: dict) -> str:
    names = result["models"]
    counts = result["counts"]
    perturbed = (f" and {counts['train_perturbed']} perturbed copies" if counts.get("train_perturbed") else "")
    lines = [f"# Spill models against MuJoCo, held-out scenes ({', '.join(result['data'])})", "",
             f"Routes within 10% of the rover's delivered mass (mean over {result['layouts']} particle layouts), "
             "held-out scenes (never in a fit); the classes count the routes the fabric planned. Fitted on "
             f"{counts['train']} training routes{perturbed}; {counts['heldout']} planned routes held out.", "",
             "| class | routes | " + " | ".join(names) + " | physics delivered / spilled / left | "
             + " / ".join(f"{n} delivered" for n in names) + " | layouts apart (median) |",
             "|---|---:|" + "---:|" * len(names) + "---:|---:|---:|"]
    for cls, row in result["scores"]["heldout"].items():
        ph = row["physics"]
        lines.append(f"| {cls} | {row['routes']} | "
                     + " | ".join(f"{row['models'][n]['within_10pct']:.0%}" for n in names)
                     + f" | {ph['delivered']:.1f} / {ph['spilled']:.1f} / {ph['left_behind']:.1f} | "
                     + " / ".join(f"{row['models'][n]['delivered']:.1f}" for n in names)
                     + f" | {ph['layout_spread_median']:.1%} |")
    train = result["scores"]["train"]["all"]["models"]
    lines += ["", "Training routes, all classes: " + ", ".join(f"{n} {train[n]['within_10pct']:.0%}" for n in names)
              + ". Median relative error held out: " + ", ".join(
                  f"{n} {result['scores']['heldout']['all']['models'][n]['median_rel_error']:.1%}" for n in names)
              + ".", "",
              f"Default spill model: `{result['default']}` ({result['default_reason']}).", "",
              *_hidden_line(result["learned"]),
              "Full build with Eq. 6 (build_fabric + reselect of every source) on a "
              f"{result['build_cost']['shape'][0]} x {result['build_cost']['shape'][1]} piles scene, median of "
              f"{result['build_cost']['repeats']}, against ROVER_FIT's: "
              + ", ".join(f"{n} {r:.2f}x" for n, r in result["build_cost"]["ratio_to_ROVER_FIT"].items()) + ".", ""]
    return "\n".join(lines)


def _hidden_line(learned: dict) -> list[str]:
    shares = learned.get("validation_within_10pct") or {}
    if not shares:
        return []
    return [f"The learned model's hidden size ({learned['hidden']}) was chosen on validation scenes of the training "
            "seeds (1, 5, 9, ...) before any held-out score, routes within 10% there: "
            + ", ".join(f"{h} units {v:.0%}" for h, v in shares.items()) + ".", ""]


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m experiments.spill_models", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="examples:\n  python -m experiments.spill_models\n"
                                            "  python -m experiments.spill_models --write-fit")
    parser.add_argument("--data", type=Path, nargs="+", default=None,
                        help="data set archives (.npz) made on the same scenes; default "
                             + " and ".join(map(str, DEFAULT_DATA)) + " (the second where it exists)")
    parser.add_argument("--hidden", type=int, nargs="+", default=list(HIDDEN),
                        help="hidden sizes of the learned model to choose from on validation scenes of the "
                             "training seeds; default " + " ".join(map(str, HIDDEN)))
    parser.add_argument("--steps", type=int, default=1500, help="Adam steps of the learned fit; default 1500")
    parser.add_argument("--results-dir", type=Path, default=Path("experiments/results"))
    parser.add_argument("--stem", default="spill_models", help="results file stem; default spill_models")
    parser.add_argument("--write-fit", action="store_true", help=f"write the learned parameters to {FIT_FILE}")
    parser.add_argument("--fit-file", type=Path, default=FIT_FILE, help=argparse.SUPPRESS)
    parser.add_argument("--seeds", type=int, default=None, help="only the scenes of seeds below this (a quick run)")
    parser.add_argument("--cost-size", type=int, default=48, help="grid side of the build-cost scene; default 48")
    parser.add_argument("--cost-repeats", type=int, default=5, help="timed builds per model; default 5")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke test: 20 steps per fit, a coarse capacity grid and miss search "
                             "(use with --seeds)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    if args.data is None:
        args.data = [DEFAULT_DATA[0]] + [p for p in DEFAULT_DATA[1:] if p.exists()]
    for path in args.data:
        if not path.exists():
            parser.error(f"--data: {path} does not exist; make it with python -m experiments.spill_data "
                         f"--out {path.with_suffix('')}")
    if min(args.hidden) < 1:
        parser.error(f"--hidden: sizes must be >= 1; got {args.hidden}")
    for flag, value, least in (("--steps", args.steps, 1), ("--seeds", args.seeds, 1),
                               ("--cost-size", args.cost_size, 8), ("--cost-repeats", args.cost_repeats, 1)):
        if value is not None and value < least:
            parser.error(f"{flag}: must be >= {least}; got {value}")
    t0 = time.perf_counter()
    routes = load_routes(args.data, args.seeds)
    if routes["heldout"].all() or not routes["heldout"].any():
        parser.error("--seeds: the scenes kept need both training and held-out seeds "
                     "(held out: every fourth seed, 3, 7, ...); use --seeds 4 or more")
    models = fit_models(routes, 20 if args.quick else args.steps, not args.no_progress, args.quick, args.hidden)
    scores = score(routes, models)
    cost = build_cost(models, (args.cost_size, args.cost_size), args.cost_repeats,
                      only=("ROVER_FIT", "learned") if args.quick else None)
    held = scores["heldout"]["all"]["models"]
    better = held["learned"]["within_10pct"] > held["ROVER_FIT"]["within_10pct"]
    manifests = [json.loads(p.with_suffix(".json").read_text()) if p.with_suffix(".json").exists() else {}
                 for p in args.data]
    route_ids = routes["route"]

    def n_routes(rows):
        return int(len(np.unique(route_ids[rows])))

    planned = ~routes["perturbed"]
    result = {
        "data": [str(p) for p in args.data], "data_sha256": [m.get("sha256") for m in manifests], "seeds": args.seeds,
        "layouts": int(np.bincount(route_ids).max()),
        "counts": {"heldout": n_routes(routes["heldout"] & planned), "train": n_routes(~routes["heldout"] & planned),
                   "heldout_perturbed": n_routes(routes["heldout"] & ~planned),
                   "train_perturbed": n_routes(~routes["heldout"] & ~planned)},
        "models": [n for n in models if not n.startswith("_")],
        "scores": scores,
        "default": "learned" if better else "ROVER_FIT",
        "default_reason": ("it predicts more held-out routes within 10% than ROVER_FIT" if better else
                           "the learned model does not beat it held out"),
        "quick": args.quick,
        "learned": {"steps": 20 if args.quick else args.steps, "final_loss": float(models["_learned_losses"][-1]),
                    "hidden": models["_hidden"], "validation_within_10pct": models["_validation"],
                    "params": learned_to_json(models["learned"])},
        "fitted": {"curvature": {k: float(getattr(models["curvature"], k)) for k in ("lam", "threshold")},
                   "capacity": {k: float(getattr(models["capacity"], k)) for k in
                                ("capacity", "lam", "mu", "miss", "turn_saturation")}},
        "build_cost": cost,
        "seconds": round(time.perf_counter() - t0, 1),
        "machine": platform.platform(),
    }
    write_results(args.results_dir, args.stem, result, markdown(result))
    if args.write_fit:
        source = "python -m experiments.spill_models --data " + " ".join(map(str, args.data))
        fit = {"source": source, "data_sha256": result["data_sha256"], "steps": args.steps,
               "hidden": models["_hidden"], **learned_to_json(models["learned"])}
        args.fit_file.write_text(json.dumps(fit, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
