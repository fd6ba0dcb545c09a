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
from experiments.spill_data import family_scene

DEFAULT_DATA = Path("experiments/data/spill.npz")
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


def load_routes(path: Path, seeds: int | None = None) -> dict:
    """The data set's records as model inputs: ``data`` (a ``tune.SpillData`` over records, delivered
    and spilled as physics measured them: spilled = collected - delivered), per-record arrays
    (``heldout``, ``family``, ``density``, ``route``: an id shared by a route's layouts), and the
    physics outcomes. Scenes are rebuilt from their family, density and seed. ``seeds``: keep only
    the scenes of seeds below it (a quick run)."""
    from jaxplan.tune import SpillData

    d = dict(np.load(path))
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
        raise ValueError(f"{path}: the rebuilt routes collect other masses than the data set records; "
                         "was it written by another version of experiments/spill_data.py?")
    perturbed = d.get("perturbed", np.zeros_like(d["entry"]))    # data sets before --perturbed have none
    key = np.stack([scene_of, d["source"][:, 0], d["source"][:, 1], d["entry"], perturbed], 1)
    _, route = np.unique(key, axis=0, return_inverse=True)
    delivered = d["delivered"].astype(np.float32)
    return {"data": SpillData(way, npt, pick, delivered, d["collected"] - delivered),
            "heldout": d["scene_heldout"][scene_of], "family": d["scene_family"][scene_of],
            "density": d["scene_density"][scene_of], "route": route.reshape(-1),
            "collected": d["collected"], "delivered": delivered, "spilled": d["spilled"],
            "left_behind": d["left_behind"], "lost": d["lost"]}


def _subset(data, rows):
    return type(data)(*(np.asarray(x)[rows] for x in data))


def fit_models(routes: dict, steps: int, progress: bool, quick: bool = False) -> dict:
    """Every model of the comparison, fitted on the training records (``quick``: a few steps each and
    a coarse capacity grid, a smoke test)."""
    from jaxplan import tune
    from jaxplan.transport.spillage import FIT_GRID, ROVER_FIT, SpillParams, fit_capacity

    train = np.where(~routes["heldout"])[0]
    data = _subset(routes["data"], train)
    fit_steps = {"steps": 20, "polish_steps": 5} if quick else {}
    curvature = tune.fit_spill(data, SpillParams(lam=0.05, threshold=0.1, temperature=0.01), **fit_steps).params
    grid = {k: v[::3] for k, v in FIT_GRID.items()} if quick else None
    capacity = fit_capacity(data.waypoints, data.n_points, data.pickup, data.delivered,
                            fields=("capacity", "lam", "mu", "turn_saturation"), grid=grid,
                            steps=20 if quick else 300, left_behind=routes["left_behind"][train]).params
    learned = tune.fit_learned(data, steps=steps, progress=progress)
    return {"curvature": curvature, "capacity": capacity, "ROVER_FIT": ROVER_FIT, "learned": learned.params,
            "_learned_losses": learned.losses}


def _per_route(values, route):
    """Mean of ``values`` over each route's records, indexed by route id."""
    return np.bincount(route, values) / np.bincount(route)


def score(routes: dict, models: dict) -> dict:
    """Per split, per density class and family: within-10% share, median relative error and masses."""
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
              "density": routes["density"][first]}
    predicted = {}
    for name, params in models.items():
        if name.startswith("_"):
            continue
        delivered, _ = jax.jit(predict_spill)(params, inputs)
        predicted[name] = np.asarray(delivered, np.float64)
    out = {}
    for split, in_split in (("heldout", groups["heldout"]), ("train", ~groups["heldout"])):
        classes = {"all": in_split}
        for density in np.unique(groups["density"]):
            classes[f"density {density:g}"] = in_split & np.isclose(groups["density"], density)
        for family in np.unique(groups["family"]):
            classes[str(family)] = in_split & (groups["family"] == family)
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
    lines = [f"# Spill models against MuJoCo, held-out scenes ({result['data']})", "",
             f"Routes within 10% of the rover's delivered mass (mean over {result['layouts']} particle layouts), "
             "held-out scenes (never in a fit). Fitted on "
             f"{result['counts']['train']} training routes; {result['counts']['heldout']} held out.", "",
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
              "Full build with Eq. 6 (build_fabric + reselect of every source) on a "
              f"{result['build_cost']['shape'][0]} x {result['build_cost']['shape'][1]} piles scene, median of "
              f"{result['build_cost']['repeats']}, against ROVER_FIT's: "
              + ", ".join(f"{n} {r:.2f}x" for n, r in result["build_cost"]["ratio_to_ROVER_FIT"].items()) + ".", ""]
    return "\n".join(lines)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m experiments.spill_models", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="examples:\n  python -m experiments.spill_models\n"
                                            "  python -m experiments.spill_models --write-fit")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help=f"data set (.npz); default {DEFAULT_DATA}")
    parser.add_argument("--steps", type=int, default=1500, help="Adam steps of the learned fit; default 1500")
    parser.add_argument("--results-dir", type=Path, default=Path("experiments/results"))
    parser.add_argument("--stem", default="spill_models", help="results file stem; default spill_models")
    parser.add_argument("--write-fit", action="store_true", help=f"write the learned parameters to {FIT_FILE}")
    parser.add_argument("--fit-file", type=Path, default=FIT_FILE, help=argparse.SUPPRESS)
    parser.add_argument("--seeds", type=int, default=None, help="only the scenes of seeds below this (a quick run)")
    parser.add_argument("--cost-size", type=int, default=48, help="grid side of the build-cost scene; default 48")
    parser.add_argument("--cost-repeats", type=int, default=5, help="timed builds per model; default 5")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke test: 20 steps per fit, a coarse capacity grid (use with --seeds)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    if not args.data.exists():
        parser.error(f"--data: {args.data} does not exist; make it with python -m experiments.spill_data "
                     f"--out {args.data.with_suffix('')}")
    for flag, value, least in (("--steps", args.steps, 1), ("--seeds", args.seeds, 1),
                               ("--cost-size", args.cost_size, 8), ("--cost-repeats", args.cost_repeats, 1)):
        if value is not None and value < least:
            parser.error(f"{flag}: must be >= {least}; got {value}")
    t0 = time.perf_counter()
    routes = load_routes(args.data, args.seeds)
    if routes["heldout"].all() or not routes["heldout"].any():
        parser.error("--seeds: the scenes kept need both training and held-out seeds "
                     "(held out: every fourth seed, 3, 7, ...); use --seeds 4 or more")
    models = fit_models(routes, 20 if args.quick else args.steps, not args.no_progress, args.quick)
    scores = score(routes, models)
    cost = build_cost(models, (args.cost_size, args.cost_size), args.cost_repeats,
                      only=("ROVER_FIT", "learned") if args.quick else None)
    held = scores["heldout"]["all"]["models"]
    better = held["learned"]["within_10pct"] > held["ROVER_FIT"]["within_10pct"]
    manifest = json.loads(args.data.with_suffix(".json").read_text()) if args.data.with_suffix(".json").exists() else {}
    route_ids = routes["route"]
    heldout_routes = int(len(np.unique(route_ids[routes["heldout"]])))
    result = {
        "data": str(args.data), "data_sha256": manifest.get("sha256"), "seeds": args.seeds,
        "layouts": int(np.bincount(route_ids).max()),
        "counts": {"heldout": heldout_routes, "train": int(len(np.unique(route_ids))) - heldout_routes},
        "models": [n for n in models if not n.startswith("_")],
        "scores": scores,
        "default": "learned" if better else "ROVER_FIT",
        "default_reason": ("it predicts more held-out routes within 10% than ROVER_FIT" if better else
                           "the learned model does not beat it held out"),
        "quick": args.quick,
        "learned": {"steps": 20 if args.quick else args.steps, "final_loss": float(models["_learned_losses"][-1]),
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
        args.fit_file.write_text(json.dumps({"source": f"python -m experiments.spill_models --data {args.data}",
                                             "data_sha256": manifest.get("sha256"), "steps": args.steps,
                                             **learned_to_json(models["learned"])}, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
