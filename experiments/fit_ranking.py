"""Learned ranking weights: fit lambda_p and eta (Eqs. 8-9) on the search's records of training
scenes, then run the tuned and the paper's weights side by side on held-out Table I scenes.

    python -m experiments.fit_ranking                            # collect, fit, evaluate
    python -m experiments.fit_ranking --train-nominal 6 --train-density 0 --draws 2 \\
        --eval-nominal 4 --eval-density 0                        # a small smoke run
    python -m experiments.fit_ranking --weights 1,1.6,0.35       # evaluate given weights only

1. Collect. Training scenes: ``nominal_scene(s)`` for s = 1000.. (``--train-nominal``) and
   ``density_scene(s, n)`` for s = 1000.. and n in ``--densities`` (``--train-density`` per n); seeds
   disjoint from the evaluation's 0-39. Each scene is planned ``--draws`` times, with the paper's
   weights and with weights drawn log-uniformly around them (lambda_p and eta times e^U(-s, s), s =
   ``--spread``; lambda_t = 1), the gap recorder on (``plan_pushes(..., record=True)``).
2. Labels. Per scene the successful run with the fewest simulated pushes (``--label best``; ties:
   fewer pushes, then the earlier draw) supplies the labelled expansions: at each node on its
   solution's path, the gap that led to the solution. ``--label all``: every successful run, weighted
   by ``exp(-(sims - best sims) / best sims)``.
3. Fit. ``jaxplan.tune.fit_ranking`` (listwise softmax loss through ``gap_costs``; lambda_t held at 1).
4. Evaluate (the Table I protocol of ``experiments/table1.py``, planner "ours"): held-out nominal seeds
   0..``--eval-nominal``-1 (60 s) and density scenes n in ``--densities``, seeds 0..``--eval-density``-1
   (120 s); per trial the world and simulator are built outside the timer and a fresh ModeTable is
   used; both weight sets run on the same scene one after the other (paired; which goes first
   alternates between scenes).

Every training run and evaluation trial is appended to ``<out>/fit_ranking_train.jsonl.gz`` /
``fit_ranking_eval.jsonl`` as soon as it ends, and a rerun skips those already there (resume; pass
``--fresh`` to start over). ``<out>/fit_ranking.json`` and ``.md`` are rewritten after every trial.
The machine is a 2-core CPU shared with other work: planning times are noisy; compare within a run.
"""
from __future__ import annotations

import argparse
import contextlib
import gzip
import io
import json
import math
import time
from pathlib import Path

import numpy as np

from experiments.results_io import write_results
from experiments.table1 import HARNESS_MAX_EXPANSIONS, make_scene
from jaxplan.pusharound import PresearchFeatures, RankingParams, build_push_world, make_push_simulator
from jaxplan.pusharound.search import ExpansionRecord, SearchConfig, plan_pushes
from jaxplan.tune import fit_ranking, ranking_data

RESULTS = Path(__file__).resolve().parent / "results"
TRAIN_SEED0 = 1000
PAPER = RankingParams()   # lambda_t 1, lambda_p 1, eta 0.5 (the harness's "ours")


# ------------------------------------------------------------------------------------ serialisation

def record_to_json(rec: ExpansionRecord) -> dict:
    out = {f: np.asarray(getattr(rec, f)).tolist() for f in ExpansionRecord._fields if f != "features"}
    out["features"] = {f: np.asarray(getattr(rec.features, f)).tolist() for f in PresearchFeatures._fields}
    out["to_go_cost"] = None if math.isnan(float(rec.to_go_cost)) else float(rec.to_go_cost)
    return out


def record_from_json(d: dict) -> ExpansionRecord:
    feats = PresearchFeatures(np.asarray(d["features"]["first"], np.float64).reshape(-1, 2),
                              np.asarray(d["features"]["tail"], np.float64).reshape(len(d["cost"]), -1, 3),
                              np.asarray(d["features"]["mask"], bool).reshape(len(d["cost"]), -1),
                              np.asarray(d["features"]["penalty"], np.float64))
    vals = {f: np.asarray(d[f]) for f in ExpansionRecord._fields if f not in ("features", "to_go_cost")}
    vals["to_go_cost"] = np.float64(math.nan if d["to_go_cost"] is None else d["to_go_cost"])
    vals["solution"] = vals["solution"].astype(bool)
    vals["endpoint"] = vals["endpoint"].astype(bool)
    return ExpansionRecord(features=feats, **vals)


# ------------------------------------------------------------------------------------------ trials

def weights_of(params: RankingParams) -> list:
    return [float(params.lambda_t), float(params.lambda_p), float(params.eta)]


def draw_weights(scene_index: int, draws: int, spread: float) -> list:
    """The paper's weights, then ``draws - 1`` log-uniform perturbations of lambda_p and eta."""
    rng = np.random.default_rng(7919 * scene_index + 13)
    out = [PAPER]
    for _ in range(draws - 1):
        f = np.exp(rng.uniform(-spread, spread, 2))
        out.append(PAPER.replace(lambda_p=float(PAPER.lambda_p * f[0]), eta=float(PAPER.eta * f[1])))
    return out


def plan(scene, world, sim, params: RankingParams, seed: int, time_limit: float, record: bool):
    cfg = SearchConfig(time_limit_s=time_limit, seed=seed, max_expansions=HARNESS_MAX_EXPANSIONS)
    return plan_pushes(scene, cfg, params, world=world, sim=sim, record=record)


def trial_row(res) -> dict:
    return {"success": bool(res.success), "reason": res.reason, "planning_time_s": float(res.stats.planning_time_s),
            "simulated_pushes": int(res.stats.simulated_pushes), "expansions": int(res.stats.expansions),
            "pushes": len(res.schedule)}


def scene_list(kind_counts: list, densities: list, seed0: int) -> list:
    """[(kind, seed, n)]: ``kind_counts`` = [(kind, count)]; density scenes for every n."""
    out = []
    for kind, count in kind_counts:
        for n in (densities if kind == "density" else [None]):
            out += [(kind, seed0 + s, n) for s in range(count)]
    return out


def _open(path: Path, mode: str):
    # The training runs carry their records: gzip (each append a new gzip member; reading joins them).
    return gzip.open(path, mode + "t") if path.suffix == ".gz" else path.open(mode)


def _read(path: Path) -> list:
    if not path.exists():
        return []
    with _open(path, "r") as fh:
        return [json.loads(line) for line in fh if line.strip()]


def _append(path: Path, row: dict) -> None:
    with _open(path, "a") as fh:
        fh.write(json.dumps(row) + "\n")


# ----------------------------------------------------------------------------------------- phases

def collect(args, out: Path, bar_factory) -> list:
    path = out / "fit_ranking_train.jsonl.gz"
    rows = _read(path)
    done = {(r["scene"], r["seed"], r["density_n"], r["draw"]) for r in rows}
    scenes = scene_list([("nominal", args.train_nominal), ("density", args.train_density)], args.densities,
                        TRAIN_SEED0)
    todo = [(i, sc, d) for i, sc in enumerate(scenes) for d in range(args.draws) if (*sc, d) not in done]
    bar = bar_factory(todo, "collect")
    world_of = {}
    for i, (kind, seed, n), d in bar:
        bar.set_postfix_str(f"{kind}{'' if n is None else n} seed {seed} draw {d}")
        if (kind, seed, n) not in world_of:
            scene = make_scene(kind, seed, n)
            world = build_push_world(scene)
            world_of = {(kind, seed, n): (scene, world, make_push_simulator(world, "auto"))}
        scene, world, sim = world_of[(kind, seed, n)]
        params = draw_weights(i, args.draws, args.spread)[d]
        limit = args.time_limit if kind == "nominal" else args.density_time_limit
        res = plan(scene, world, sim, params, seed, limit, True)
        row = {"scene": kind, "seed": seed, "density_n": n, "draw": d, "weights": weights_of(params),
               **trial_row(res), "records": [record_to_json(r) for r in res.records]}
        _append(path, row)
        rows.append(row)
    return rows


def labelled(rows: list, mode: str) -> tuple:
    """(records, weights) of the runs that label the fit (module docstring, step 2)."""
    by_scene: dict = {}
    for r in rows:
        by_scene.setdefault((r["scene"], r["seed"], r["density_n"]), []).append(r)
    records, weights = [], []
    for runs in by_scene.values():
        ok = [r for r in runs if r["success"] and r["records"]]
        if not ok:
            continue
        best = min(ok, key=lambda r: (r["simulated_pushes"], r["pushes"], r["draw"]))
        chosen = [(best, 1.0)] if mode == "best" else [
            (r, math.exp(-(r["simulated_pushes"] - best["simulated_pushes"]) / max(best["simulated_pushes"], 1)))
            for r in ok]
        for r, w in chosen:
            recs = [record_from_json(x) for x in r["records"]]
            records += recs
            weights += [w] * len(recs)
    return records, weights


def training_oracle(rows: list) -> dict:
    """Per scene kind: the median simulated pushes of the training runs with the paper's weights (draw
    0) and of each scene's best successful draw (a per-scene oracle over the draws)."""
    out = {}
    for kind in sorted({r["scene"] for r in rows}):
        paper, best = [], {}
        for r in rows:
            if r["scene"] != kind:
                continue
            if r["draw"] == 0:
                paper.append(r["simulated_pushes"])
            k = (r["seed"], r["density_n"])
            if r["success"] and (k not in best or r["simulated_pushes"] < best[k]):
                best[k] = r["simulated_pushes"]
        out[kind] = {"scenes": len(paper), "median_sims_paper": float(np.median(paper)) if paper else None,
                     "median_sims_best_draw": float(np.median(list(best.values()))) if best else None}
    return out


def evaluate(args, out: Path, tuned: RankingParams, bar_factory, summary) -> list:
    path = out / "fit_ranking_eval.jsonl"
    key = weights_of(tuned)
    rows = [r for r in _read(path) if r["weight_set"] == "paper" or r["weights"] == key]
    done = {(r["scene"], r["seed"], r["density_n"], r["weight_set"]) for r in rows}
    scenes = scene_list([("nominal", args.eval_nominal), ("density", args.eval_density)], args.densities, 0)
    # Alternate which weight set goes first on a scene (any warm cache is shared evenly).
    todo = [(sc, name) for i, sc in enumerate(scenes) for name in (("paper", "tuned"), ("tuned", "paper"))[i % 2]
            if (*sc, name) not in done]
    bar = bar_factory(todo, "evaluate")
    for (kind, seed, n), name in bar:
        bar.set_postfix_str(f"{kind}{'' if n is None else n} seed {seed} {name}")
        # As table1.py: a fresh world and simulator per trial, so each planning time includes the same
        # policy compile.
        scene = make_scene(kind, seed, n)
        world = build_push_world(scene)
        sim = make_push_simulator(world, "auto")
        params = PAPER if name == "paper" else tuned
        limit = args.time_limit if kind == "nominal" else args.density_time_limit
        res = plan(scene, world, sim, params, seed, limit, False)
        row = {"scene": kind, "seed": seed, "density_n": n, "weight_set": name, "weights": weights_of(params),
               "n_movables": len(scene.movables), **trial_row(res),
               "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        _append(path, row)
        rows.append(row)
        summary(rows, quiet=True)
    return rows


# ---------------------------------------------------------------------------------------- summary

def paired_summary(rows: list) -> list:
    """Per scene group (nominal; density n; density 35-45 together): each weight set's success, median
    planning time, expansions and simulated pushes over the scenes both ran, and the paired change."""
    groups = {"nominal": lambda r: r["scene"] == "nominal",
              "density (all n)": lambda r: r["scene"] == "density"}
    for n in sorted({r["density_n"] for r in rows if r["scene"] == "density"}):
        groups[f"density N={n}"] = (lambda n: lambda r: r["scene"] == "density" and r["density_n"] == n)(n)
    out = []
    for name, pick in groups.items():
        pairs: dict = {}
        for r in rows:
            if pick(r):
                pairs.setdefault((r["scene"], r["seed"], r["density_n"]), {})[r["weight_set"]] = r
        both = [p for p in pairs.values() if "paper" in p and "tuned" in p]
        if not both:
            continue
        row = {"group": name, "scenes": len(both)}
        for ws in ("paper", "tuned"):
            rs = [p[ws] for p in both]
            row[ws] = {"success_pct": 100.0 * sum(r["success"] for r in rs) / len(rs),
                       "median_planning_time_s": float(np.median([r["planning_time_s"] for r in rs])),
                       "median_expansions": float(np.median([r["expansions"] for r in rs])),
                       "median_simulated_pushes": float(np.median([r["simulated_pushes"] for r in rs])),
                       "mean_simulated_pushes": float(np.mean([r["simulated_pushes"] for r in rs])),
                       "median_pushes_solved": (float(np.median([r["pushes"] for r in rs if r["success"]]))
                                                if any(r["success"] for r in rs) else None)}
        a = np.array([p["paper"]["simulated_pushes"] for p in both], np.float64)
        b = np.array([p["tuned"]["simulated_pushes"] for p in both], np.float64)
        rel = (b - a) / np.maximum(a, 1.0)
        row["paired"] = {"median_relative_change_sims": float(np.median(rel)),
                         "change_of_median_sims": float(np.median(b) / max(np.median(a), 1.0) - 1.0),
                         "tuned_fewer": int(np.sum(b < a)), "equal": int(np.sum(b == a)),
                         "tuned_more": int(np.sum(b > a))}
        row["target_met"] = bool(row["paired"]["median_relative_change_sims"] <= -0.2
                                 and row["tuned"]["success_pct"] >= row["paper"]["success_pct"])
        out.append(row)
    return out


def markdown(doc: dict) -> str:
    w = doc["fit"]["weights"]
    t = doc["fit"]["temperature"]
    source = ("given with --weights" if t is None else
              f"listwise temperature {t:.3g}; {doc['fit']['expansions']} labelled expansions from "
              f"{doc['fit']['training_runs']} training runs ({doc['fit']['training_scenes']} scenes)")
    lines = ["# Learned ranking weights (held-out, paired)", "",
             f"Generated by `experiments/fit_ranking.py`. Tuned weights lambda_t / lambda_p / eta = "
             f"{w[0]:.3g} / {w[1]:.3g} / {w[2]:.3g} (paper: 1 / 1 / 0.5); {source}. {doc['note']}", ""]
    for kind, o in (doc["fit"].get("training_oracle") or {}).items():
        lines += [f"Training, {kind} ({o['scenes']} scenes): median simulated pushes {o['median_sims_paper']:g} with "
                  f"the paper's weights, {o['median_sims_best_draw']:g} with each scene's best weight draw (a "
                  "per-scene oracle over the draws).", ""]
    lines += [
             "Per weight set: Succ. %, median planning time (s), median expansions, median simulated pushes. "
             "Paired: median over scenes of (tuned - paper) / paper simulated pushes; the change of the medians; "
             "scenes where tuned simulated fewer / as many / more. Target: paired median <= -20% at equal or "
             "better success.", "",
             "| Group | Scenes | Paper: succ · PT · exp · sims | Tuned: succ · PT · exp · sims | Paired median Δsims "
             "| Δ of medians | fewer / equal / more | Target |",
             "|---|---:|---|---|---:|---:|---|---|"]
    for r in doc["rows"]:
        cell = {ws: f"{r[ws]['success_pct']:.1f} · {r[ws]['median_planning_time_s']:.2f} · "
                    f"{r[ws]['median_expansions']:g} · {r[ws]['median_simulated_pushes']:g}"
                for ws in ("paper", "tuned")}
        p = r["paired"]
        lines.append(f"| {r['group']} | {r['scenes']} | {cell['paper']} | {cell['tuned']} | "
                     f"{100 * p['median_relative_change_sims']:+.1f}% | {100 * p['change_of_median_sims']:+.1f}% | "
                     f"{p['tuned_fewer']} / {p['equal']} / {p['tuned_more']} | "
                     f"{'met' if r['target_met'] else 'not met'} |")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------- main

def parse(argv=None):
    ap = argparse.ArgumentParser(prog="python -m experiments.fit_ranking", description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m experiments.fit_ranking --train-nominal 24 "
                                        "--train-density 2 --draws 4 --eval-nominal 40 --eval-density 5",
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--train-nominal", type=int, default=24, help="training nominal scenes (seeds 1000..)")
    ap.add_argument("--train-density", type=int, default=2, help="training density scenes per n (seeds 1000..)")
    ap.add_argument("--densities", default="35,40,45", help="movable counts of the density scenes")
    ap.add_argument("--draws", type=int, default=4, help="weight sets per training scene (the first: the paper's)")
    ap.add_argument("--spread", type=float, default=1.0, help="log half-width of the weight draws")
    ap.add_argument("--label", choices=("best", "all"), default="best", help="which training runs label the fit")
    ap.add_argument("--steps", type=int, default=400, help="Adam steps of fit_ranking")
    ap.add_argument("--lr", type=float, default=0.05, help="fit_ranking's learning rate")
    ap.add_argument("--eval-nominal", type=int, default=40, help="held-out nominal scenes (seeds 0..)")
    ap.add_argument("--eval-density", type=int, default=5, help="held-out density scenes per n (seeds 0..)")
    ap.add_argument("--time-limit", type=float, default=60.0, help="planning limit of a nominal trial [s]")
    ap.add_argument("--density-time-limit", type=float, default=120.0, help="planning limit of a density trial [s]")
    ap.add_argument("--weights", default=None, help="lambda_t,lambda_p,eta: evaluate these, no collection or fit")
    ap.add_argument("--out", default=str(RESULTS), help="output folder")
    ap.add_argument("--fresh", action="store_true", help="delete this script's JSONL files first")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    args.densities = [int(x) for x in args.densities.split(",") if x.strip()]
    for name in ("train_nominal", "train_density", "eval_nominal", "eval_density"):
        if getattr(args, name) < 0:
            ap.error(f"--{name.replace('_', '-')}: must be >= 0")
    if args.draws < 1 or args.steps < 1 or not args.spread >= 0 or not args.lr > 0:
        ap.error("--draws and --steps must be >= 1, --spread >= 0 and --lr > 0")
    return args


def main(argv=None) -> dict:
    args = parse(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.fresh:
        for stem in ("fit_ranking_train.jsonl.gz", "fit_ranking_eval.jsonl"):
            (out / stem).unlink(missing_ok=True)
    from tqdm import tqdm  # noqa: PLC0415

    def bar_factory(items, desc):
        return tqdm(items, desc=desc, disable=args.no_progress, dynamic_ncols=True)

    fit_info = {"weights": None, "temperature": None, "expansions": 0, "training_runs": 0, "training_scenes": 0,
                "losses": None, "args": {k: v for k, v in vars(args).items() if k != "out"}}
    if args.weights:
        lt, lp, eta = (float(x) for x in args.weights.split(","))
        tuned = RankingParams(lambda_t=lt, lambda_p=lp, eta=eta)
    else:
        rows = collect(args, out, bar_factory)
        records, weights = labelled(rows, args.label)
        data = ranking_data(records, weights=weights)
        fit = fit_ranking(data, steps=args.steps, learning_rate=args.lr)
        tuned = fit.params
        scenes = {(r["scene"], r["seed"], r["density_n"]) for r in rows}
        fit_info.update(temperature=fit.temperature, expansions=int(data.valid.shape[0]), training_runs=len(rows),
                        training_scenes=len(scenes), losses=[float(x) for x in np.asarray(fit.losses)[::20]],
                        training_oracle=training_oracle(rows))
    fit_info["weights"] = weights_of(tuned)
    print(f"tuned weights lambda_t / lambda_p / eta = {fit_info['weights']}", flush=True)

    def summary(rows, quiet=False) -> dict:
        doc = {"note": "2-core CPU shared with other work: planning times are noisy; compare within this run.",
               "fit": fit_info, "rows": paired_summary(rows), "trials_file": "fit_ranking_eval.jsonl",
               "training_file": "fit_ranking_train.jsonl.gz"}
        with contextlib.redirect_stdout(io.StringIO()) if quiet else contextlib.nullcontext():
            write_results(out, "fit_ranking", doc, markdown(doc))
        return doc

    rows = evaluate(args, out, tuned, bar_factory, summary)
    return summary(rows)


if __name__ == "__main__":
    main()
