"""Benchmark of the rover bridge (issue 7, section 4): physics outcomes, lambda fit, throughput.

Part 1 (physics outcomes, C engine): the first ``--routes`` routes (sources with the largest J, as
``bridge.plan_routes``) of the built-in scenes ``default`` and ``corridor`` are rolled out in one
batch per scene with ``bridge.check_routes(..., backend="c")``. Per route: collected and delivered
particle mass (objects), mean / max lateral error of the blade point (cells), finite.

Part 2 (lambda fit): the 2D prediction of delivered mass for a route is
``spillage.evaluate_route(execute.waypoints(route), execute.waypoint_pickup(route), SpillParams(lam))``
(the curvature spill model on the route's spline). ``lam`` minimises the sum of squared errors
(predicted - simulated delivered mass) over a set of routes by a 1-D search: a grid of 201 values on
[0, 5], then golden-section search (60 iterations) in the bracket around the best grid point. Fits:
on all routes (in-sample), and scene-held-out (fit on ``default``, test on ``corridor`` and vice
versa). Reported before (lam = 0.05, the default) and after the fit: RMSE, mean |error| / simulated,
and the issue's target fraction: routes with mean lateral error < 0.25 cell AND simulated delivered
mass within 10% of the fitted prediction (|sim - pred| <= 0.1 pred).

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

    python experiments/bench_rover.py --quick      # 2 routes per scene, tiny MJX comparison only
    python experiments/bench_rover.py              # 4 routes per scene, both MJX comparisons
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

RESULTS_DIR = Path(__file__).resolve().parent / "results"
SCENES = ("default", "corridor")
LAM_DEFAULT = 0.05
LAM_RANGE = (0.0, 5.0)
TARGET_LATERAL = 0.25      # cells
TARGET_REL = 0.10          # |sim - pred| <= 10% of pred
TARGET_FRACTION = 0.95


# --------------------------------------------------------------------------------------------------
# 2D prediction and the lambda fit
# --------------------------------------------------------------------------------------------------

def _route_inputs(scene, routes):
    """Per route: ``(waypoints f32[S+1, 2], n_points, pickup f32[S+1])`` for ``evaluate_route``."""
    from jaxplan import execute
    from jaxplan.physics import bridge

    out = []
    for i in range(int(np.asarray(routes.n_cells).shape[0])):
        r = bridge._index(routes, i)
        pts, n = execute.waypoints(scene, r)
        pickup, _ = execute.waypoint_pickup(scene, r)
        out.append((np.asarray(pts), int(n), np.asarray(pickup)))
    return out


def make_predictor(inputs):
    """``predict(lams f[L]) -> f[L, R]``: 2D delivered mass of every route for every lambda."""
    import jax
    import jax.numpy as jnp

    from jaxplan import spillage

    s_max = max(p.shape[0] for p, _, _ in inputs)

    def pad(a, n):
        return np.concatenate([a, np.repeat(a[-1:], n - a.shape[0], 0)], 0) if a.shape[0] < n else a

    pts = jnp.asarray(np.stack([pad(p, s_max) for p, _, _ in inputs]), jnp.float32)
    npts = jnp.asarray([n for _, n, _ in inputs], jnp.int32)
    pick = jnp.asarray(np.stack([np.concatenate([k, np.zeros(s_max - k.shape[0])]) for _, _, k in inputs]),
                       jnp.float32)

    def one(lam, p, n, k):
        return spillage.evaluate_route(p, n, k, spillage.SpillParams(lam=lam))[0]

    per_lam = jax.jit(jax.vmap(jax.vmap(one, in_axes=(None, 0, 0, 0)), in_axes=(0, None, None, None)))
    return lambda lams: np.asarray(per_lam(jnp.asarray(np.atleast_1d(lams), jnp.float32), pts, npts, pick),
                                   np.float64)


def fit_lambda(predict, sim, idx):
    """Minimise sum (predict(lam)[idx] - sim[idx])^2 over lam in LAM_RANGE: grid + golden section."""
    idx = np.asarray(idx)
    loss = lambda lam: float(np.sum((predict(lam)[0, idx] - sim[idx]) ** 2))
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


def errors(pred, sim, lateral, idx):
    idx = np.asarray(idx)
    p, s, lat = pred[idx], sim[idx], lateral[idx]
    within = np.abs(s - p) <= TARGET_REL * np.maximum(p, 1e-9)
    ok = within & (lat < TARGET_LATERAL)
    return {
        "n": int(idx.size),
        "rmse": float(np.sqrt(np.mean((p - s) ** 2))),
        "mean_abs_err": float(np.mean(np.abs(p - s))),
        "mean_rel_err_vs_sim": float(np.mean(np.abs(p - s) / np.maximum(s, 1e-9))),
        "frac_within_10pct": float(np.mean(within)),
        "frac_target": float(np.mean(ok)),
    }


# --------------------------------------------------------------------------------------------------
# Throughput
# --------------------------------------------------------------------------------------------------

def _small_scene():
    from jaxplan.scene import Scene, box

    obj = np.zeros((6, 12))
    obj[1, 2:5] = [1, 2, 1]
    obj[3, 1:4] = [2, 1, 1]
    obj[4, 5] = 2
    return Scene.from_arrays(obj, box(9.0, 0.0, 12.0, 6.0), name="small")


def throughput(scene, n_routes, n_ticks, repeats, label):
    """Same routes, same world, both engines: cold and warm wall time, routes x steps per second."""
    from jaxplan.physics import bridge, rover
    from jaxplan.physics.rollout import Simulator

    _, routes, _ = bridge.plan_routes(scene, n_routes=n_routes)
    b = int(np.asarray(routes.n_cells).shape[0])
    masks = [bridge._route_mask(scene, bridge._index(routes, i)) for i in range(b)]
    need = max(len(rover.particle_layout(scene, m, seed=i)[0]) for i, m in enumerate(masks))
    world = rover.build_world(scene, need)
    sub = world.config.substeps
    res = {"label": label, "scene": scene.name, "routes": b, "ticks": n_ticks, "substeps": sub,
           "particle_bodies": world.n_particles, "nq": int(world.model.nq), "engines": {}}
    outcomes = {}
    for be in ("c", "mjx"):
        sim = Simulator(world.model, bridge.pursuit_policy, substeps=sub, bounds=world.bounds, backend=be)
        t0 = time.perf_counter()
        chk = bridge.check_routes(scene, routes, n_ticks=n_ticks, world=world, simulator=sim)
        cold = time.perf_counter() - t0
        warm = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            chk = bridge.check_routes(scene, routes, n_ticks=n_ticks, world=world, simulator=sim)
            warm.append(time.perf_counter() - t0)
        w = float(np.median(warm))
        steps = b * n_ticks * sub
        res["engines"][be] = {"cold_s": cold, "warm_s": warm, "warm_median_s": w,
                              "compile_overhead_s": cold - w,
                              "route_steps_per_s": steps / w, "route_ticks_per_s": b * n_ticks / w,
                              "finite": [bool(x) for x in chk.outcome.finite]}
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
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 routes per scene, small-scene MJX comparison only")
    ap.add_argument("--routes", type=int, default=None, help="routes per scene (default 4, 2 with --quick)")
    ap.add_argument("--repeats", type=int, default=2, help="warm repeats per engine in the throughput part")
    ap.add_argument("--tp-ticks", type=int, default=120, help="control ticks in the throughput comparison")
    args = ap.parse_args(argv)
    n_routes = args.routes or (2 if args.quick else 4)

    import jax

    from jaxplan import builtin_scene
    from jaxplan.physics import bridge

    t_start = time.perf_counter()
    rows, inputs, scene_of = [], [], []
    sim_runs = {}
    for name in SCENES:
        scene = builtin_scene(name)
        _, routes, sources = bridge.plan_routes(scene, n_routes=n_routes)
        t0 = time.perf_counter()
        chk = bridge.check_routes(scene, routes, backend="c")
        dt = time.perf_counter() - t0
        b = int(np.asarray(routes.n_cells).shape[0])
        sim_runs[name] = {"routes": b, "ticks": chk.n_ticks, "particle_bodies": chk.world.n_particles,
                          "wall_s": dt, "route_steps_per_s": b * chk.n_ticks * chk.world.config.substeps / dt}
        print(f"{name}: {b} routes x {chk.n_ticks} ticks, {chk.world.n_particles} particle bodies, "
              f"C engine {dt:.1f} s", flush=True)
        for i, row in enumerate(chk.outcome.rows()):
            row.update(scene=name, source=[int(v) for v in sources[i]],
                       n_cells=int(np.asarray(routes.n_cells)[i]), fallback=bool(np.asarray(routes.fallback)[i]))
            rows.append(row)
            scene_of.append(name)
        inputs += _route_inputs(scene, routes)

    sim = np.array([r["delivered"] for r in rows])
    collected = np.array([r["collected"] for r in rows])
    lateral = np.array([r["mean_lateral"] for r in rows])
    finite = np.array([r["finite"] for r in rows])
    scene_of = np.array(scene_of)
    predict = make_predictor(inputs)
    pred0 = predict(LAM_DEFAULT)[0]
    pred_lam0 = predict(0.0)[0]   # = collected by the 2D model (no spill)
    every = np.arange(len(rows))

    lam_all, loss_all, curve = fit_lambda(predict, sim, every)
    pred_fit = predict(lam_all)[0]
    fits = {"all": {"lam": lam_all, "sse": loss_all,
                    "before": errors(pred0, sim, lateral, every), "after": errors(pred_fit, sim, lateral, every)}}
    for train in SCENES:
        tr = np.nonzero(scene_of == train)[0]
        te = np.nonzero(scene_of != train)[0]
        lam_t, sse_t, _ = fit_lambda(predict, sim, tr)
        pt = predict(lam_t)[0]
        fits[f"fit_on_{train}"] = {"lam": lam_t, "sse_train": sse_t,
                                   "train": errors(pt, sim, lateral, tr), "held_out": errors(pt, sim, lateral, te),
                                   "held_out_before": errors(pred0, sim, lateral, te)}
        # diagnostic, not the 2D model: a constant blade capacity (mean simulated delivery of the
        # training scene) as the prediction for every route
        cap = float(np.mean(sim[tr]))
        fits[f"fit_on_{train}"]["capacity_baseline"] = {
            "capacity": cap, "held_out": errors(np.full_like(sim, cap), sim, lateral, te)}
    for i, r in enumerate(rows):
        r["pred_2d_collected"] = float(pred_lam0[i])
        r["pred_delivered_lam_default"] = float(pred0[i])
        r["pred_delivered_lam_fit"] = float(pred_fit[i])
        r["within_10pct_fit"] = bool(abs(sim[i] - pred_fit[i]) <= TARGET_REL * max(pred_fit[i], 1e-9))
        r["meets_target"] = bool(r["within_10pct_fit"] and lateral[i] < TARGET_LATERAL)
    turn = []
    for p, n, _ in inputs:
        from jaxplan import spillage
        smp = spillage.sample_route(p, n, 8)
        turn.append(float(np.sum(np.abs(np.asarray(smp.turn)))))
    for r, t in zip(rows, turn):
        r["total_turn_rad"] = t

    print("throughput (C vs MJX, same batch) ...", flush=True)
    tp = [throughput(_small_scene(), 2, args.tp_ticks, args.repeats, "small scene")]
    if not args.quick:
        tp.append(throughput(builtin_scene("default"), 2, 40, args.repeats, "default scene, short horizon"))

    result = {
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "host": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": os.cpu_count(),
                 "jax": jax.__version__, "jax_devices": [str(d) for d in jax.devices()],
                 "mujoco": __import__("mujoco").__version__},
        "quick": bool(args.quick), "routes_per_scene": n_routes,
        "fit_method": "grid of 201 lam on [0, 5], then 60 golden-section iterations around the best grid point; "
                      "loss = sum of squared (2D predicted - simulated) delivered mass",
        "targets": {"mean_lateral_lt_cells": TARGET_LATERAL, "delivered_rel_tol": TARGET_REL,
                    "fraction": TARGET_FRACTION},
        "physics_runs": sim_runs, "routes": rows, "fits": fits, "lam_curve_all": curve,
        "summary": {"collected": float(collected.sum()), "delivered_sim": float(sim.sum()),
                    "delivered_pred_default": float(pred0.sum()), "delivered_pred_fit": float(pred_fit.sum()),
                    "all_finite": bool(finite.all()),
                    "frac_lateral_ok": float(np.mean(lateral < TARGET_LATERAL)),
                    "frac_target_fit_all": fits["all"]["after"]["frac_target"]},
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
    L = [f"# Rover benchmark (issue 7) {'(quick)' if r['quick'] else ''}".rstrip(), "",
         f"{r['date']}, {r['host']['platform']}, {r['host']['cpus']} CPUs, jax {r['host']['jax']}, "
         f"mujoco {r['host']['mujoco']}, devices {r['host']['jax_devices']}. No GPU lent: CPU only.", "",
         f"## Routes (C engine; first {r['routes_per_scene']} routes by J per scene)", "",
         "| scene | source | cells | collected | sim delivered | 2D pred lam=0.05 | 2D pred lam_fit "
         "| total turn (rad) | mean lat (cell) | max lat (cell) | finite | target met |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for x in r["routes"]:
        L.append(f"| {x['scene']} | {tuple(x['source'])} | {x['n_cells']} | {x['collected']:.0f} | {x['delivered']:.0f} "
                 f"| {x['pred_delivered_lam_default']:.1f} | {x['pred_delivered_lam_fit']:.1f} | {x['total_turn_rad']:.2f} "
                 f"| {x['mean_lateral']:.3f} | {x['max_lateral']:.3f} | {x['finite']} | {x['meets_target']} |")
    f = r["fits"]
    L += ["", f"## Lambda fit ({r['fit_method']})", "",
          "| fit | lam | evaluated on | n | RMSE (objects) | mean abs err | mean rel err vs sim "
          "| within 10% of pred | lateral < 0.25 AND within 10% |",
          "|---|---|---|---|---|---|---|---|---|"]

    def line(fit, lam, on, e):
        return (f"| {fit} | {lam} | {on} | {e['n']} | {e['rmse']:.2f} | {e['mean_abs_err']:.2f} "
                f"| {e['mean_rel_err_vs_sim']:.2f} | {e['frac_within_10pct']:.2f} | {e['frac_target']:.2f} |")
    L.append(line("none (default)", f"{LAM_DEFAULT}", "all routes", f["all"]["before"]))
    L.append(line("all routes", f"{f['all']['lam']:.3f}", "all routes (in-sample)", f["all"]["after"]))
    for s in SCENES:
        g = f[f"fit_on_{s}"]
        other = next(o for o in SCENES if o != s)
        L.append(line(f"{s} only", f"{g['lam']:.3f}", f"{s} (in-sample)", g["train"]))
        L.append(line(f"{s} only", f"{g['lam']:.3f}", f"{other} (held out)", g["held_out"]))
    L += ["", "Diagnostic (not the 2D model): a constant blade capacity C = mean simulated delivery of the "
          "training scene, as the prediction for every route of the other scene: " + "; ".join(
              f"fit on {s}: C = {f[f'fit_on_{s}']['capacity_baseline']['capacity']:.1f}, held-out RMSE "
              f"{f[f'fit_on_{s}']['capacity_baseline']['held_out']['rmse']:.2f}, within 10% "
              f"{f[f'fit_on_{s}']['capacity_baseline']['held_out']['frac_within_10pct']:.2f}" for s in SCENES) + "."]
    sm = r["summary"]
    L += ["", f"Totals: collected {sm['collected']:.0f}, simulated delivered {sm['delivered_sim']:.0f}, "
          f"2D predicted {sm['delivered_pred_default']:.1f} (lam = 0.05) and {sm['delivered_pred_fit']:.1f} "
          f"(lam = {f['all']['lam']:.3f}). All rollouts finite: {sm['all_finite']}. "
          f"Routes with mean lateral error < 0.25 cell: {sm['frac_lateral_ok']:.2f}. "
          f"Issue target (>= {r['targets']['fraction']:.0%} of routes with both): "
          f"{sm['frac_target_fit_all']:.2f} -> {'met' if sm['frac_target_fit_all'] >= r['targets']['fraction'] else 'NOT met'}.",
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
        f"{t['label']}: delivered C {t['agreement']['delivered']['c']} vs MJX {t['agreement']['delivered']['mjx']}, "
        "largest mean-lateral-error difference "
        f"{max(abs(a - b) for a, b in zip(t['agreement']['mean_lateral']['c'], t['agreement']['mean_lateral']['mjx'])):.4f} cell"
        for t in r["throughput"])
    L += ["", f"The throughput horizons are slices of the routes ({agree}). The C engine's cost per step follows "
          "the contacts actually active (C-engine route-steps/s: " + ", ".join(
              f"{t['label']} {t['engines']['c']['route_steps_per_s']:,.0f}" for t in r["throughput"]) +
          "; whole routes: " + ", ".join(f"{k} {v['route_steps_per_s']:,.0f}" for k, v in r["physics_runs"].items()) +
          "), MJX's is set by its contact caps (every capped pair is evaluated every step, active or "
          "not), so the ratio on whole routes would be of the same order; full-route C-engine rates are in the "
          "next line.",
          "", "Physics runs of the route table (C engine, cold, including scoring): " + "; ".join(
        f"{k}: {v['routes']} routes x {v['ticks']} ticks, {v['particle_bodies']} particle bodies, {v['wall_s']:.1f} s "
        f"({v['route_steps_per_s']:,.0f} route-steps/s)" for k, v in r["physics_runs"].items()) + ".",
        f"Total script time {r['total_s']:.0f} s.", ""]
    return "\n".join(L)


if __name__ == "__main__":
    raise SystemExit(main())
