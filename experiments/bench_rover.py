"""Benchmark of the rover bridge: physics outcomes, lambda fit, throughput.

Part 1 (physics outcomes, C engine): the first ``--routes`` routes (sources with the largest J, as
``bridge.plan_routes``) of the built-in scenes ``default``, ``corridor``, ``two_targets`` and
``sparse65`` are rolled out in one batch per scene with ``bridge.check_routes(..., backend="c")``,
the blade driving ``--push-in`` cells past each route's end, each under ``--layouts`` particle
layouts (same counts, different jitter). Per route: collected and delivered particle mass (objects;
the mean over layouts, every layout's delivery kept), mean / max lateral error of the blade point
(cells; the worst layout), reached, finite (every layout). The mean is what the 2D model, which sees
only the counts, can predict; the fraction of single rollouts within 10% is reported beside it.

Part 2 (fits of the 2D spill model to the simulated deliveries). Models: the curvature model
(``spillage.curvature_spill``, ``lam`` only, 1-D grid + golden section on the squared error), the
capacity-aware model (``spill_capacity.capacity_spill``: ``capacity``, ``lam``, ``mu`` by
``spill_fit.fit_capacity``: coarse grid vmapped over parameter sets, then Adam), the same model
with its two turning terms (``miss`` fitted to the objects left on the routes' cells, then
``capacity``, ``lam``, ``mu``, ``turn_saturation`` to the deliveries), and a diagnostic constant (the
training routes' mean delivery). Splits: in-sample; routes held out (fit on routes 0, 2,
4 of every scene, score on 1, 3, 5); scenes held out (leave one scene out). Scored: RMSE, mean
|error| / simulated, and the issue's target fraction: routes with mean lateral error < 0.25 cell AND
simulated delivered mass within 10% of the fitted prediction (|sim - pred| <= 0.1 pred), counted for
the turning model in sample (the issue's "fitted 2D prediction") and reported held out too. A noise
floor: one route rolled out with ``--noise-reps`` particle layouts (same counts, different jitter).

Part 3 (throughput, same run, CPU): the same batch of routes x control ticks rolled out on the C
engine and on MJX (``rollout.Simulator``, same world, same policy). Each engine runs once cold (MJX:
tracing + XLA compilation; C: jit of the batched policy) and ``--repeats`` times warm; warm numbers
are medians. Throughput = routes x physics steps (ticks x substeps) per second. MJX compiles slowly
on a CPU and its step cost grows with the contact caps, so the comparison uses a small scene of our
own (a few piles on a 6 x 12 grid) and, without ``--quick``, also the default scene's first routes
on a short horizon. Timings are wall clock on whatever CPU runs the script (here: 2 cores shared
with other jobs), so treat them as indicative.

Results: a markdown table on stdout, ``experiments/results/rover.json`` and ``rover.md``
(``rover_quick.*`` with ``--quick``).

Examples::

    python -m experiments.bench_rover --quick      # 2 routes per scene, tiny MJX comparison only
    python -m experiments.bench_rover              # 6 routes per scene, both MJX comparisons
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from jaxplan.transport.physics import check_routes, plan_routes, pursuit_policy, world_for_routes
from jaxplan.transport.spillage import (
    FIT_FIELDS,
    SpillParams,
    evaluate_route,
    fit_capacity,
    predict_delivered,
    predict_missed,
    sample_route,
)

RESULTS_DIR = Path(__file__).resolve().parent / "results"
SCENES = ("default", "corridor", "two_targets", "sparse65")
PUSH_IN = 1.0              # cells the blade drives on past a route's end (bridge.check_routes)
NOISE_SCENE = "default"
TEMPERATURE = 0.5          # objects: softness of the capacity model's blade limit (held fixed in fits)
LAM_DEFAULT = 0.05
LAM_RANGE = (0.0, 5.0)
TARGET_LATERAL = 0.25      # cells
TARGET_REL = 0.10          # |sim - pred| <= 10% of pred
TARGET_FRACTION = 0.95


# --------------------------------------------------------------------------------------------------
# 2D prediction and the lambda fit
# --------------------------------------------------------------------------------------------------

def route_inputs(scene, routes):
    """Per route: ``(waypoints f32[S+1, 2], n_points, pickup f32[S+1])`` for ``evaluate_route``."""
    import jax

    from jaxplan.transport import waypoint_pickup, waypoints

    out = []
    for i in range(int(np.asarray(routes.n_cells).shape[0])):
        r = jax.tree_util.tree_map(lambda a: a[i], routes)
        pts, n = waypoints(scene, r)
        pickup, _ = waypoint_pickup(scene, r)
        out.append((np.asarray(pts), int(n), np.asarray(pickup)))
    return out


def make_predictor(inputs):
    """``predict(lams f[L]) -> f[L, R]``: 2D delivered mass of every route for every lambda."""
    import jax
    import jax.numpy as jnp


    s_max = max(p.shape[0] for p, _, _ in inputs)

    def pad(a, n):
        return np.concatenate([a, np.repeat(a[-1:], n - a.shape[0], 0)], 0) if a.shape[0] < n else a

    pts = jnp.asarray(np.stack([pad(p, s_max) for p, _, _ in inputs]), jnp.float32)
    npts = jnp.asarray([n for _, n, _ in inputs], jnp.int32)
    pick = jnp.asarray(np.stack([np.concatenate([k, np.zeros(s_max - k.shape[0])]) for _, _, k in inputs]),
                       jnp.float32)

    def one(lam, p, n, k):
        return evaluate_route(p, n, k, SpillParams(lam=lam))[0]

    per_lam = jax.jit(jax.vmap(jax.vmap(one, in_axes=(None, 0, 0, 0)), in_axes=(0, None, None, None)))
    return lambda lams: np.asarray(per_lam(jnp.asarray(np.atleast_1d(lams), jnp.float32), pts, npts, pick),
                                   np.float64)


def stack_inputs(inputs):
    """Padded ``(waypoints f32[R, S, 2], n_points i32[R], pickup f32[R, S])`` of every route."""
    s_max = max(p.shape[0] for p, _, _ in inputs)
    pts = np.stack([np.concatenate([p, np.repeat(p[-1:], s_max - p.shape[0], 0)], 0) for p, _, _ in inputs])
    pick = np.stack([np.concatenate([k, np.zeros(s_max - k.shape[0])]) for _, _, k in inputs])
    return pts.astype(np.float32), np.array([n for _, n, _ in inputs], np.int32), pick.astype(np.float32)


def fit_capacity_model(stacked, sim, idx, steps, left=None):
    """``(params, predict_all f[R])``: ``spill_fit.fit_capacity`` on the routes ``idx``.

    left: None for the three-term model (capacity, lam, mu); else f[R] simulated objects left on the
    routes' cells, and the model with the turning terms: ``miss`` fitted to ``left`` first, then
    capacity, lam, mu and turn_saturation to the deliveries.
    """

    pts, n, pick = stacked
    idx = np.asarray(idx)
    extra = {} if left is None else {"fields": FIT_FIELDS, "left_behind": left[idx]}
    fit = fit_capacity(pts[idx], n[idx], pick[idx], sim[idx], temperature=TEMPERATURE, steps=steps, **extra)
    pred = np.asarray(predict_delivered(pts, n, pick, fit.params), np.float64)
    return fit, pred


def fit_lambda(predict, sim, idx):
    """Minimise sum (predict(lam)[idx] - sim[idx])^2 over lam in LAM_RANGE: grid + golden section."""
    idx = np.asarray(idx)

    def loss(lam):
        return float(np.sum((predict(lam)[0, idx] - sim[idx]) ** 2))

    grid = np.linspace(*LAM_RANGE, 201)
    losses = np.sum((predict(grid)[:, idx] - sim[idx][None]) ** 2, 1)
    k = int(np.argmin(losses))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    g = (math.sqrt(5) - 1) / 2
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = loss(c), loss(d)
    for _ in range(60):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = loss(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = loss(d)
    lam = (a + b) / 2
    best = min((loss(lam), lam), (float(losses[k]), float(grid[k])))
    return float(best[1]), float(best[0]), {"grid": grid.tolist(), "loss": losses.tolist()}


def layout_row(rollouts):
    """One route's row from its rollouts under several particle layouts (``RouteOutcome.rows()``).

    Masses are layout means (the 2D model predicts a route's expected delivery from the counts
    alone; one rollout is one draw of the particle layout); ``delivered_layouts`` keeps every draw.
    Lateral errors are the worst layout's; ``reached`` / ``finite`` hold only if they hold for all.
    """
    row = {}
    for key, v0 in rollouts[0].items():
        vals = [r[key] for r in rollouts]
        if isinstance(v0, bool):
            row[key] = all(vals)
        elif key in ("mean_lateral", "max_lateral", "max_contacts", "time"):
            row[key] = max(vals)
        else:
            row[key] = float(np.mean(vals))
    row["delivered_layouts"] = [r["delivered"] for r in rollouts]
    return row


def within_target(sim, pred):
    """``bool[...]``: simulated delivery within ``TARGET_REL`` of the prediction (|sim - pred| <= 0.1 pred)."""
    pred = np.asarray(pred, np.float64)
    return np.abs(np.asarray(sim, np.float64) - pred) <= TARGET_REL * np.maximum(pred, 1e-9)


def errors(pred, sim, lateral, idx, sim_layouts=None):
    """Scores of predictions ``pred f[R]`` against simulated ``sim f[R]`` (layout means) on routes
    ``idx``; with ``sim_layouts`` (R lists of single-rollout deliveries) also the fraction of single
    rollouts within 10% of their route's prediction."""
    idx = np.asarray(idx)
    p, s, lat = pred[idx], sim[idx], lateral[idx]
    within = within_target(s, p)
    ok = within & (lat < TARGET_LATERAL)
    out = {
        "n": int(idx.size),
        "rmse": float(np.sqrt(np.mean((p - s) ** 2))),
        "mean_abs_err": float(np.mean(np.abs(p - s))),
        "mean_rel_err_vs_sim": float(np.mean(np.abs(p - s) / np.maximum(s, 1e-9))),
        "frac_within_10pct": float(np.mean(within)),
        "frac_target": float(np.mean(ok)),
    }
    if sim_layouts is not None:
        single = [within_target(v, pred[i]) for i in idx for v in sim_layouts[i]]
        out["frac_single_rollouts_within_10pct"] = float(np.mean(single))
    return out


# --------------------------------------------------------------------------------------------------
# Throughput
# --------------------------------------------------------------------------------------------------

def small_scene():
    from jaxplan.transport import Scene, box

    obj = np.zeros((6, 12))
    obj[1, 2:5] = [1, 2, 1]
    obj[3, 1:4] = [2, 1, 1]
    obj[4, 5] = 2
    return Scene.from_arrays(obj, box(9.0, 0.0, 12.0, 6.0), name="small")


def throughput(scene, n_routes, n_ticks, repeats, label):
    """Same routes, same world, both engines: cold and warm wall time, routes x steps per second.

    n_ticks None: whole routes (``check_routes``' horizon, fixed by the first engine's run and reused).
    """
    from jaxplan.physics import Simulator

    _, routes, _ = plan_routes(scene, n_routes=n_routes)
    b = int(np.asarray(routes.n_cells).shape[0])
    world = world_for_routes(scene, routes)
    sub = world.config.substeps
    res = {"label": label, "scene": scene.name, "routes": b, "ticks": n_ticks, "substeps": sub,
           "particle_bodies": world.n_particles, "nq": int(world.model.nq), "engines": {}}
    outcomes = {}
    for be in ("c", "mjx"):
        sim = Simulator(world.model, pursuit_policy, substeps=sub, bounds=world.bounds, backend=be)
        t0 = time.perf_counter()
        chk = check_routes(scene, routes, n_ticks=n_ticks, world=world, simulator=sim)
        n_ticks = res["ticks"] = chk.n_ticks
        cold = time.perf_counter() - t0
        warm = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            chk = check_routes(scene, routes, n_ticks=n_ticks, world=world, simulator=sim)
            warm.append(time.perf_counter() - t0)
        w = float(np.median(warm))
        steps = b * n_ticks * sub
        res["engines"][be] = {"cold_s": cold, "warm_s": warm, "warm_median_s": w,
                              "compile_overhead_s": cold - w,
                              "route_steps_per_s": steps / w, "route_ticks_per_s": b * n_ticks / w,
                              "finite": [bool(x) for x in chk.outcome.finite],
                              "reached": [bool(x) for x in chk.outcome.reached]}
        outcomes[be] = chk.outcome
        print(f"  [{label}] {be}: cold {cold:.1f} s, warm {w:.2f} s, {steps / w:,.0f} route-steps/s",
              flush=True)
    e = res["engines"]
    res["c_over_mjx"] = e["c"]["route_steps_per_s"] / e["mjx"]["route_steps_per_s"]
    res["agreement"] = {k: {"c": getattr(outcomes["c"], k).tolist(), "mjx": getattr(outcomes["mjx"], k).tolist()}
                        for k in ("delivered", "mean_lateral")}
    return res


# --------------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------------

def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m experiments.bench_rover", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 routes per scene, small-scene MJX comparison only")
    ap.add_argument("--routes", type=int, default=None, help="routes per scene (default 4, 2 with --quick)")
    ap.add_argument("--repeats", type=int, default=2, help="warm repeats per engine in the throughput part")
    ap.add_argument("--tp-ticks", type=int, default=0,
                    help="control ticks of the small-scene throughput comparison (default 0: whole routes)")
    ap.add_argument("--push-in", type=float, default=PUSH_IN,
                    help=f"cells the blade drives on past each route's end (default {PUSH_IN})")
    ap.add_argument("--fit-steps", type=int, default=300, help="Adam steps of the capacity fit")
    ap.add_argument("--noise-reps", type=int, default=6, help="particle layouts of the noise-floor route")
    ap.add_argument("--layouts", type=int, default=None,
                    help="particle layouts per route in the route table; a route's simulated delivery is their "
                         "mean (default 3, 2 with --quick)")
    args = ap.parse_args(argv)
    n_routes = args.routes or (2 if args.quick else 6)
    if args.layouts is not None and args.layouts < 1:
        ap.error("--layouts: must be >= 1")
    args.layouts = args.layouts or (2 if args.quick else 3)

    import jax

    from jaxplan import builtin_scene

    t_start = time.perf_counter()
    rows, inputs, scene_of = [], [], []
    sim_runs = {}
    for name in SCENES:
        scene = builtin_scene(name)
        _, routes, sources = plan_routes(scene, n_routes=n_routes)
        b = int(np.asarray(routes.n_cells).shape[0])
        # batch element i * L + k is route i under layout k (check_routes seeds the jitter by element)
        batch = jax.tree.map(lambda a: np.repeat(np.asarray(a), args.layouts, 0), routes)
        t0 = time.perf_counter()
        chk = check_routes(scene, batch, backend="c", push_in=args.push_in)
        dt = time.perf_counter() - t0
        nb = b * args.layouts
        sim_runs[name] = {"routes": b, "layouts": args.layouts, "rollouts": nb, "ticks": chk.n_ticks,
                          "particle_bodies": chk.world.n_particles, "wall_s": dt,
                          "route_steps_per_s": nb * chk.n_ticks * chk.world.config.substeps / dt}
        print(f"{name}: {b} routes x {args.layouts} layouts x {chk.n_ticks} ticks, {chk.world.n_particles} "
              f"particle bodies, C engine {dt:.1f} s", flush=True)
        per_rollout = chk.outcome.rows()
        for i in range(b):
            row = layout_row(per_rollout[i * args.layouts:(i + 1) * args.layouts])
            row.update(scene=name, source=[int(v) for v in sources[i]],
                       n_cells=int(np.asarray(routes.n_cells)[i]), fallback=bool(np.asarray(routes.fallback)[i]))
            rows.append(row)
            scene_of.append(name)
        inputs += route_inputs(scene, routes)

    sim = np.array([r["delivered"] for r in rows])
    sim_layouts = [r["delivered_layouts"] for r in rows]
    collected = np.array([r["collected"] for r in rows])
    lateral = np.array([r["mean_lateral"] for r in rows])
    finite = np.array([r["finite"] for r in rows])
    scene_of = np.array(scene_of)
    predict = make_predictor(inputs)
    pred0 = predict(LAM_DEFAULT)[0]
    pred_lam0 = predict(0.0)[0]   # = collected by the 2D model (no spill)
    every = np.arange(len(rows))

    stacked = stack_inputs(inputs)
    route_no = np.array([int(np.sum(scene_of[:i] == scene_of[i])) for i in range(len(rows))])
    # Splits: in-sample (fit and score on every route); routes held out (fit on the even-numbered
    # routes of every scene, score on the odd ones); scenes held out (leave one scene out: each
    # scene's routes are predicted by the fit on the other scenes; scored over all routes).
    splits = {"in_sample": [(every, every)],
              "routes_held_out": [(np.nonzero(route_no % 2 == 0)[0], np.nonzero(route_no % 2 == 1)[0])],
              "scenes_held_out": [(np.nonzero(scene_of != sc_)[0], np.nonzero(scene_of == sc_)[0])
                                  for sc_ in SCENES if np.any(scene_of == sc_)]}
    left = np.array([r["left_behind"] for r in rows])
    fits = {"curvature": {}, "capacity": {}, "turning": {}, "constant": {}}
    held_pred = {m: {} for m in fits}
    for split, folds in splits.items():
        for model in fits:
            pred_split = np.full(len(rows), np.nan)
            params = []
            for tr, te in folds:
                if model == "curvature":
                    lam_t, _, _ = fit_lambda(predict, sim, tr)
                    pt = predict(lam_t)[0]
                    params.append({"lam": lam_t})
                elif model in ("capacity", "turning"):
                    fit, pt = fit_capacity_model(stacked, sim, tr, args.fit_steps,
                                                 left if model == "turning" else None)
                    shown = ("capacity", "lam", "mu", "temperature") + (
                        ("miss", "turn_saturation") if model == "turning" else ())
                    params.append({k: float(getattr(fit.params, k)) for k in shown})
                else:   # diagnostic baseline: the training routes' mean delivery for every route
                    pt = np.full(len(rows), float(np.mean(sim[tr])))
                    params.append({"mean": float(np.mean(sim[tr]))})
                pred_split[te] = pt[te]
            test = np.unique(np.concatenate([te for _, te in folds]))
            fits[model][split] = {"params": params, **errors(pred_split, sim, lateral, test, sim_layouts)}
            held_pred[model][split] = pred_split
        print(f"  fits [{split}]: " + ", ".join(f"{m} RMSE {fits[m][split]['rmse']:.2f} within10% "
                                                  f"{fits[m][split]['frac_within_10pct']:.2f}" for m in fits),
              flush=True)
    # the miss term against what it was fitted to: objects left on the routes' own cells
    miss_in = fits["turning"]["in_sample"]["params"][0]["miss"]
    pred_left = np.asarray(predict_missed(*stacked, miss_in), np.float64)
    fits["turning"]["in_sample"]["left_behind"] = {
        "miss": miss_in, "rmse": float(np.sqrt(np.mean((pred_left - left) ** 2))),
        "corr": float(np.corrcoef(pred_left, left)[0, 1]) if np.std(left) > 0 and np.std(pred_left) > 0 else None,
        "sim_total": float(left.sum()), "pred_total": float(pred_left.sum())}
    fits["curvature"]["default_lam"] = {"params": [{"lam": LAM_DEFAULT}],
                                        **errors(pred0, sim, lateral, every, sim_layouts)}
    pred_fit = held_pred["curvature"]["in_sample"]
    pred_cap = held_pred["capacity"]["in_sample"]
    pred_cap_loso = held_pred["capacity"]["scenes_held_out"]
    pred_turn = held_pred["turning"]["in_sample"]
    pred_turn_loso = held_pred["turning"]["scenes_held_out"]
    for i, r in enumerate(rows):
        r["route_no"] = int(route_no[i])
        r["pred_2d_collected"] = float(pred_lam0[i])
        r["pred_delivered_lam_default"] = float(pred0[i])
        r["pred_delivered_lam_fit"] = float(pred_fit[i])
        r["pred_delivered_capacity_fit"] = float(pred_cap[i])
        r["pred_delivered_capacity_scene_held_out"] = float(pred_cap_loso[i])
        r["pred_delivered_turning_fit"] = float(pred_turn[i])
        r["pred_left_behind_turning_fit"] = float(pred_left[i])
        r["pred_delivered_turning_scene_held_out"] = float(pred_turn_loso[i])
        r["within_10pct_in_sample"] = bool(within_target(sim[i], pred_turn[i]))
        r["within_10pct_held_out"] = bool(within_target(sim[i], pred_turn_loso[i]))
        r["meets_target"] = bool(r["within_10pct_in_sample"] and lateral[i] < TARGET_LATERAL)
        r["meets_target_scene_held_out"] = bool(r["within_10pct_held_out"] and lateral[i] < TARGET_LATERAL)
    turn = []
    for p, n, _ in inputs:
        smp = sample_route(p, n, 8)
        turn.append(float(np.sum(np.abs(np.asarray(smp.turn)))))
    for r, t in zip(rows, turn):
        r["total_turn_rad"] = t

    # Noise floor: the same route with different particle layouts (check_routes seeds each batch
    # element's jitter by its index). The spread of these deliveries bounds how close any 2D model,
    # which sees only the counts, can get to the simulated delivery of one rollout.
    print("noise floor (one route, several particle layouts) ...", flush=True)
    import jax as _jax
    scene = builtin_scene(NOISE_SCENE)
    _, routes, sources = plan_routes(scene, n_routes=1)
    reps = _jax.tree.map(lambda a: np.repeat(np.asarray(a)[:1], args.noise_reps, 0), routes)
    chk = check_routes(scene, reps, backend="c", push_in=args.push_in)
    rep = np.asarray(chk.outcome.delivered, np.float64)
    centre = float(np.median(rep))
    noise = {"scene": NOISE_SCENE, "source": [int(v) for v in sources[0]], "collected": float(chk.outcome.collected[0]),
             "delivered": rep.tolist(), "mean": float(rep.mean()), "std": float(rep.std(ddof=1)),
             "median": centre,
             "frac_within_10pct_of_median": float(np.mean(np.abs(rep - centre) <= TARGET_REL * centre)),
             "mean_lateral": np.asarray(chk.outcome.mean_lateral).tolist()}
    print(f"  delivered over {args.noise_reps} layouts: {rep.tolist()}", flush=True)

    print("throughput (C vs MJX, same batch) ...", flush=True)
    tp = [throughput(small_scene(), 2, args.tp_ticks or None, args.repeats,
                     "small scene, whole routes" if not args.tp_ticks else "small scene")]
    if not args.quick:
        tp.append(throughput(builtin_scene("default"), 2, 40, args.repeats, "default scene, short horizon"))

    result = {
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "host": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": os.cpu_count(),
                 "jax": jax.__version__, "jax_devices": [str(d) for d in jax.devices()],
                 "mujoco": __import__("mujoco").__version__},
        "quick": bool(args.quick), "routes_per_scene": n_routes, "layouts_per_route": args.layouts,
        "push_in_cells": args.push_in,
        "fit_method": {
            "curvature": "lam only: grid of 201 lam on [0, 5], then 60 golden-section iterations around the best "
                         "grid point; loss = sum of squared (2D predicted - simulated) delivered mass",
            "capacity": f"spill_fit.fit_capacity: capacity, lam, mu; temperature {TEMPERATURE} fixed; coarse "
                        f"grid (vmap over parameter sets) then {args.fit_steps} Adam steps (optax), mean squared error",
            "turning": "capacity model with the two turning terms: miss fitted to the simulated objects left on the "
                       "routes' cells (spill_fit.fit_miss, least squares), then capacity, lam, mu and "
                       f"turn_saturation as above ({args.fit_steps} Adam steps)",
            "constant": "diagnostic, not a route model: the training routes' mean simulated delivery"},
        "splits": {"in_sample": "fit and score on every route",
                   "routes_held_out": "fit on routes 0, 2, 4, ... of every scene, score on routes 1, 3, 5, ...",
                   "scenes_held_out": "leave one scene out: each scene's routes predicted by the fit on the others"},
        "targets": {"mean_lateral_lt_cells": TARGET_LATERAL, "delivered_rel_tol": TARGET_REL,
                    "fraction": TARGET_FRACTION},
        "physics_runs": sim_runs, "routes": rows, "fits": fits, "noise_floor": noise,
        "summary": {"collected": float(collected.sum()), "delivered_sim": float(sim.sum()),
                    "delivered_pred_default": float(pred0.sum()), "delivered_pred_lam_fit": float(pred_fit.sum()),
                    "delivered_pred_capacity_fit": float(pred_cap.sum()),
                    "delivered_pred_turning_fit": float(pred_turn.sum()),
                    "all_finite": bool(finite.all()), "all_reached": bool(all(r["reached"] for r in rows)),
                    "frac_lateral_ok": float(np.mean(lateral < TARGET_LATERAL)),
                    "frac_target_capacity_scenes_held_out": fits["capacity"]["scenes_held_out"]["frac_target"],
                    "frac_target_capacity_routes_held_out": fits["capacity"]["routes_held_out"]["frac_target"],
                    "frac_target_capacity_in_sample": fits["capacity"]["in_sample"]["frac_target"],
                    **{f"frac_target_turning_{k}": fits["turning"][k]["frac_target"]
                       for k in ("in_sample", "routes_held_out", "scenes_held_out")}},
        "throughput": tp, "total_s": time.perf_counter() - t_start,
    }
    md = to_markdown(result)
    print(md)
    stem = "rover_quick" if args.quick else "rover"
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    (RESULTS_DIR / f"{stem}.json").write_text(json.dumps(result, indent=1))
    (RESULTS_DIR / f"{stem}.md").write_text(md)
    return 0


def to_markdown(r):
    L = [f"# Rover benchmark {'(quick)' if r['quick'] else ''}".rstrip(), "",
         f"{r['date']}, {r['host']['platform']}, {r['host']['cpus']} CPUs (shared with other jobs while this ran), "
         f"jax {r['host']['jax']}, mujoco {r['host']['mujoco']}, devices {r['host']['jax_devices']}. "
         "No GPU lent: CPU only.", "",
         f"## Routes (C engine; first {r['routes_per_scene']} routes by J per scene; the blade drives "
         f"{r['push_in_cells']:g} cell past each route's end)", "",
         f"Each route is rolled out under {r['layouts_per_route']} particle layouts (same counts, different "
         "jitter); 'sim delivered' is their mean (the 2D model predicts a route's expected delivery from the "
         "counts alone), the single rollouts are listed after it. Lateral errors: the worst layout.", "",
         "| scene | route | source | cells | collected | sim delivered (layouts) | 2D lam=0.05 | 2D lam fit "
         "| capacity fit | capacity, scene held out | turning fit | turning, scene held out | mean lat (cell) "
         "| max lat (cell) | reached | finite | target met (in sample / scene held out) |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for x in r["routes"]:
        L.append(f"| {x['scene']} | {x['route_no']} | {tuple(x['source'])} | {x['n_cells']} | {x['collected']:.0f} "
                 f"| {x['delivered']:.1f} ({', '.join(f'{v:.0f}' for v in x['delivered_layouts'])}) "
                 f"| {x['pred_delivered_lam_default']:.1f} | {x['pred_delivered_lam_fit']:.1f} "
                 f"| {x['pred_delivered_capacity_fit']:.1f} | {x['pred_delivered_capacity_scene_held_out']:.1f} "
                 f"| {x['pred_delivered_turning_fit']:.1f} | {x['pred_delivered_turning_scene_held_out']:.1f} "
                 f"| {x['mean_lateral']:.3f} | {x['max_lateral']:.3f} | {x['reached']} | {x['finite']} "
                 f"| {x['meets_target']} / {x['meets_target_scene_held_out']} |")
    f = r["fits"]
    L += ["", "## Fits of the 2D spill model to the simulated deliveries", ""]
    L += [f"- {k}: {v}" for k, v in r["fit_method"].items()]
    L += [f"- split {k}: {v}" for k, v in r["splits"].items()]
    L += ["", "| model | split | n scored | RMSE (objects) | mean abs err | mean rel err vs sim "
          "| within 10% of pred | lateral < 0.25 AND within 10% | single rollouts within 10% | fitted parameters |",
          "|---|---|---|---|---|---|---|---|---|---|"]

    def fmt(ps):
        return "; ".join(", ".join(f"{k} {v:.3g}" for k, v in p.items()) for p in ps)

    def line(model, split, e):
        return (f"| {model} | {split} | {e['n']} | {e['rmse']:.2f} | {e['mean_abs_err']:.2f} "
                f"| {e['mean_rel_err_vs_sim']:.2f} | {e['frac_within_10pct']:.2f} | {e['frac_target']:.2f} "
                f"| {e.get('frac_single_rollouts_within_10pct', float('nan')):.2f} | {fmt(e['params'])} |")
    L.append(line("curvature", "none (lam = 0.05)", f["curvature"]["default_lam"]))
    for model in ("curvature", "capacity", "turning", "constant"):
        for split in ("in_sample", "routes_held_out", "scenes_held_out"):
            L.append(line(model, split.replace("_", " "), f[model][split]))
    lb = f["turning"]["in_sample"]["left_behind"]
    corr = "n/a" if lb["corr"] is None else f"{lb['corr']:.2f}"
    L += ["", f"Left behind (objects on the routes' own cells after the push), in-sample `miss` {lb['miss']:.4g} per "
          f"radian against the simulation: {lb['pred_total']:.1f} predicted vs {lb['sim_total']:.1f} simulated over "
          f"all routes, RMSE {lb['rmse']:.2f} objects per route, correlation {corr}."]
    cap = f["turning"]["in_sample"]["params"][0]
    L += ["", "To predict (or plan) with the in-sample fit of the turning model: `jaxplan rover --lam {lam:.4g} "
          "--mu {mu:.4g} --capacity {capacity:.4g} --miss {miss:.4g} --turn-saturation {turn_saturation:.4g}` "
          "(the same for `episode` and `demo`; temperature {temperature:g}, the model's default). "
          "`jaxplan.transport.spillage.capacity.ROVER_FIT` holds the fit this file was written with; after a re-run "
          "that changes it, update ROVER_FIT (tests/transport/test_spill_capacity.py compares the two).".format(**cap)]
    nf = r["noise_floor"]
    L += ["", f"Noise floor: the first route of `{nf['scene']}` (source {tuple(nf['source'])}, {nf['collected']:.0f} "
          f"objects) rolled out with {len(nf['delivered'])} particle layouts (same counts, different jitter) delivered "
          f"{', '.join(f'{v:.0f}' for v in nf['delivered'])}: mean {nf['mean']:.1f}, std {nf['std']:.1f} "
          f"(coefficient of variation {nf['std'] / max(nf['mean'], 1e-9):.2f}). Their own median is within 10% of "
          f"{nf['frac_within_10pct_of_median']:.2f} of them. The 2D model sees only the counts, so a spread of "
          "single rollouts wider than 10% would limit the target whatever the spill model"
          + (" (it does here)." if nf['frac_within_10pct_of_median'] < TARGET_FRACTION else
             " (it does not here).")]
    if r.get("layouts_per_route", 1) > 1:
        spread = []
        for name in dict.fromkeys(x["scene"] for x in r["routes"]):
            d = [np.asarray(x["delivered_layouts"]) for x in r["routes"] if x["scene"] == name]
            cv = [v.std(ddof=1) / max(v.mean(), 1e-9) for v in d]
            spread.append(f"{name} {np.median(cv):.2f} (largest {max(cv):.2f}, widest range "
                          f"{max(v.max() - v.min() for v in d):.0f} objects)")
        L += ["", "Spread over layouts per route, coefficient of variation, median over the scene's routes: "
              + "; ".join(spread) + "."]
    sm = r["summary"]
    met = sm["frac_target_turning_in_sample"] >= r["targets"]["fraction"]
    L += ["", f"Totals: collected {sm['collected']:.0f}, simulated delivered {sm['delivered_sim']:.0f}, "
          f"2D predicted {sm['delivered_pred_default']:.1f} (lam = 0.05), {sm['delivered_pred_lam_fit']:.1f} "
          f"(lam fitted), {sm['delivered_pred_capacity_fit']:.1f} (capacity model fitted), "
          f"{sm['delivered_pred_turning_fit']:.1f} (turning model fitted). All rollouts finite: "
          f"{sm['all_finite']}; all reached their end: {sm['all_reached']}. "
          f"Routes with mean lateral error < 0.25 cell: {sm['frac_lateral_ok']:.2f}. "
          f"Issue target (>= {r['targets']['fraction']:.0%} of routes with both, against the fitted 2D "
          f"prediction: turning model, in sample): {sm['frac_target_turning_in_sample']:.2f} -> "
          f"{'met' if met else 'NOT met'}. Held out: routes {sm['frac_target_turning_routes_held_out']:.2f}, "
          f"scenes {sm['frac_target_turning_scenes_held_out']:.2f}. The three-term capacity model: in sample "
          f"{sm['frac_target_capacity_in_sample']:.2f}, routes held out "
          f"{sm['frac_target_capacity_routes_held_out']:.2f}, scenes held out "
          f"{sm['frac_target_capacity_scenes_held_out']:.2f}.",
          "", "## Throughput (CPU, same run, same batch on both engines; warm = median of repeats, "
          "compile = cold - warm)", "",
          "| comparison | routes | ticks x substeps | particle bodies | engine | cold (s) | warm (s) "
          "| compile/setup (s) | route-steps/s | C / MJX |",
          "|---|---|---|---|---|---|---|---|---|---|"]
    for t in r["throughput"]:
        for be in ("c", "mjx"):
            e = t["engines"][be]
            L.append(f"| {t['label']} | {t['routes']} | {t['ticks']} x {t['substeps']} | {t['particle_bodies']} | "
                     f"{'C engine' if be == 'c' else 'MJX'} | {e['cold_s']:.1f} | {e['warm_median_s']:.2f} "
                     f"| {e['compile_overhead_s']:.1f} | {e['route_steps_per_s']:,.0f} "
                     f"| {t['c_over_mjx']:.1f} |")
    agree = "; ".join(
        f"{t['label']} ({t['ticks']} ticks): reached C {t['engines']['c'].get('reached')} vs MJX "
        f"{t['engines']['mjx'].get('reached')}, "
        f"delivered C {t['agreement']['delivered']['c']} vs MJX {t['agreement']['delivered']['mjx']}, "
        "largest mean-lateral-error difference "
        + format(max(abs(a - b) for a, b in zip(t['agreement']['mean_lateral']['c'],
                                                t['agreement']['mean_lateral']['mjx'])), ".4f") + " cell"
        for t in r["throughput"])
    L += ["", f"Both engines on the same batch ({agree}). The small scene's routes are rolled out whole (MJX: one "
          "jit(vmap(scan)) over every control tick of the route); the default scene's comparison is a slice of its "
          "routes (MJX on a CPU needs minutes per whole route there). The C engine's cost per step follows "
          "the contacts actually active (C-engine route-steps/s: " + ", ".join(
              f"{t['label']} {t['engines']['c']['route_steps_per_s']:,.0f}" for t in r["throughput"]) +
          "; whole routes: " + ", ".join(f"{k} {v['route_steps_per_s']:,.0f}" for k, v in r["physics_runs"].items()) +
          "), MJX's is set by its contact caps (every capped pair is evaluated every step, active or "
          "not), so the ratio on whole routes would be of the same order; full-route C-engine rates are in the "
          "next line.",
          "", "Physics runs of the route table (C engine, cold, including scoring): " + "; ".join(
        f"{k}: {v['routes']} routes x {v.get('layouts', 1)} layouts x {v['ticks']} ticks, "
        f"{v['particle_bodies']} particle bodies, {v['wall_s']:.1f} s "
        f"({v['route_steps_per_s']:,.0f} route-steps/s)" for k, v in r["physics_runs"].items()) + ".",
        f"Total script time {r['total_s']:.0f} s.", ""]
    return "\n".join(L)


if __name__ == "__main__":
    raise SystemExit(main())
