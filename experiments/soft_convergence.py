"""How close the soft fabric is to the hard one, per temperature, on random grids; and its gradients.

For each of ``--grids`` random grids (sides 8 to 32, integer or real counts, densities 0.2-0.6,
cone angles 30-75 degrees, tau_h 0.2-0.6, circle / box / two-circle multipolygon targets; seed
``--seed``) it builds the hard fabric and the soft one at every temperature of ``TEMPERATURES`` and
measures, per field, ``max |soft - hard| / max |hard|`` (``value`` and ``raw`` against J, ``heat``
against the hard heat) and the fraction of cells where ``highways > 0.5`` equals the hard highways.
The table gives the median and max over grids per t, and how many grids are within 5% (value, raw
and heat at once) with highways equal on at least 98% of cells.

On the first ``--fd-grids`` grids of side 8 it compares ``jax.grad`` of a scalar touching every
output (value, raw, psi, heat, highways, anchor weights) with central finite differences along
random directions, w.r.t. theta_tol, tau_h, anchor_lambda and the counts, at t = 0.05 and 0.2.
Writes ``experiments/results/soft_convergence.{json,md,png}``.

    python -m experiments.soft_convergence                  # 200 grids (about 5 minutes on 1 core)
    python -m experiments.soft_convergence --grids 20
"""
from __future__ import annotations

import argparse
import datetime as _dt
import platform
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from shapely.geometry import MultiPolygon

from experiments.results_io import write_results
from jaxplan import FabricParams, Scene, box, build_fabric, circle
from jaxplan.tune import gradient_probe

RESULTS_DIR = Path(__file__).resolve().parent / "results"
TEMPERATURES = (0.5, 0.2, 0.1, 0.05, 0.02, 0.01)
SIDES = (8, 12, 16, 24, 32)
FIELDS = ("value", "raw", "heat")
FD_TEMPERATURES = (0.05, 0.2)
FD_ARGS = ("theta_tol_deg", "tau_h", "anchor_lambda", "counts")
FD_EPS = (0.05, 2e-3, 2e-2, 2e-2)
FD_REL = 0.02


def make_grid(rng: np.random.Generator):
    """``(scene, params, description)`` of one random grid."""
    side = int(rng.choice(SIDES))
    density = float(rng.uniform(0.2, 0.6))
    integer = bool(rng.random() < 0.5)
    if integer:
        counts = rng.integers(1, 6, (side, side)).astype(np.float32)
    else:
        counts = np.round(rng.uniform(0.5, 5.0, (side, side)), 3).astype(np.float32)
    obj = np.where(rng.random((side, side)) < density, counts, 0.0).astype(np.float32)
    kind = str(rng.choice(("circle", "box", "multipolygon")))
    cx, cy = rng.uniform(1.0, side - 1.0, 2)
    r = float(rng.uniform(0.8, max(1.0, side / 6)))
    if kind == "circle":
        target = circle((cx, cy), r)
    elif kind == "box":
        target = box(cx - r, cy - 0.7 * r, cx + r, cy + r)
    else:
        first = circle((cx, cy), min(r, 1.5))
        second = circle(((cx + side / 2) % side, (cy + side / 2) % side), 0.9)
        target = first if first.intersects(second) else MultiPolygon([first, second])
    params = FabricParams(theta_tol_deg=float(rng.uniform(30.0, 75.0)), tau_h=float(rng.uniform(0.2, 0.6)))
    desc = dict(side=side, density=round(density, 3), integer=integer, target=kind,
                theta_tol_deg=round(float(params.theta_tol_deg), 2), tau_h=round(float(params.tau_h), 3))
    return Scene.from_arrays(obj, target, cell_size=1.0), params, desc


def _error(soft, hard) -> float:
    soft, hard = np.asarray(soft, np.float64), np.asarray(hard, np.float64)
    return float(np.max(np.abs(soft - hard))) / max(float(np.max(np.abs(hard))), 1e-9)


def grid_errors(scene, params) -> dict:
    """``{t: {value, raw, heat, highways}}``: relative errors and highway agreement per temperature."""
    hard = build_fabric(scene, params)
    out = {}
    for t in TEMPERATURES:
        soft = build_fabric(scene, params.replace(temperature=t))
        agree = float(np.mean((np.asarray(soft.highways) > 0.5) == np.asarray(hard.highways)))
        out[t] = dict(value=_error(soft.value, hard.value), raw=_error(soft.raw, hard.value),
                      heat=_error(soft.heat, hard.heat), highways=agree)
    return out


_value = jax.jit(gradient_probe)
_grad = jax.jit(jax.grad(gradient_probe, argnums=(1, 2, 3, 4)))


def gradient_checks(scene, params, rng) -> list[dict]:
    """Analytic vs central-difference directional derivatives, one row per (t, argument). The
    counts' direction moves only occupied cells (occupancy is a hard switch)."""
    obj = jnp.asarray(scene.obj)
    x = [jnp.float32(params.theta_tol_deg), jnp.float32(params.tau_h), jnp.float32(params.anchor_lambda), obj]
    rows = []
    for t in FD_TEMPERATURES:
        grads = _grad(scene, *x, t)
        finite = all(bool(np.all(np.isfinite(np.asarray(g)))) for g in grads)
        for i, (name, eps) in enumerate(zip(FD_ARGS, FD_EPS)):
            d = rng.normal(size=np.shape(x[i])).astype(np.float32)
            if name == "counts":
                d = d * (np.asarray(obj) > 0)
            d = jnp.asarray(d)
            analytic = float(jnp.sum(grads[i] * d))
            numeric = []
            for step in (eps, eps / 3, eps / 10):   # narrow transitions: a step may cross one
                plus, minus = list(x), list(x)
                plus[i], minus[i] = x[i] + step * d, x[i] - step * d
                numeric.append((float(_value(scene, *plus, t)) - float(_value(scene, *minus, t))) / (2 * step))
            rels = [abs(analytic - n) / max(abs(n), 1.0) for n in numeric]
            best = int(np.argmin(rels))
            rows.append(dict(t=t, argument=name, analytic=analytic, numeric=numeric, rel_diffs=rels,
                             rel_diff=rels[0], best_rel_diff=rels[best], agree=rels[0] <= FD_REL,
                             agree_any_step=rels[best] <= FD_REL, finite=finite))
    return rows


def summarise(per_grid: list[dict]) -> dict:
    table = {}
    for t in TEMPERATURES:
        row = {}
        for f in FIELDS + ("highways",):
            vals = np.array([g["errors"][t][f] for g in per_grid])
            row[f] = dict(median=float(np.median(vals)), max=float(np.max(vals)) if f != "highways" else None,
                          min=float(np.min(vals)) if f == "highways" else None)
        within = [all(g["errors"][t][f] < 0.05 for f in FIELDS) and g["errors"][t]["highways"] >= 0.98
                  for g in per_grid]
        row["within_5pct"] = int(sum(within))
        for f in FIELDS:
            row[f"{f}_within_5pct"] = int(sum(g["errors"][t][f] < 0.05 for g in per_grid))
        row["highways_98pct"] = int(sum(g["errors"][t]["highways"] >= 0.98 for g in per_grid))
        table[str(t)] = row
    return table


def markdown(result: dict) -> str:
    n = result["grids"]
    lines = [f"Soft fabric vs hard fabric on {n} random grids (sides 8-32, densities 0.2-0.6, angles 30-75 deg, "
             "integer and real counts, circle / box / multipolygon targets). Error: max |soft - hard| / max hard, "
             "median (max) over grids; highways: fraction of cells where soft > 0.5 equals hard, median (min).", "",
             "| t | value | raw | heat | highways | grids within 5% (all three, highways >= 98%) | "
             "value / raw / heat within 5% | highways >= 98% |",
             "|---|---|---|---|---|---|---|---|"]
    for t, row in result["table"].items():
        cell = lambda f: f"{row[f]['median']:.4f} ({row[f]['max']:.3f})"  # noqa: E731
        lines.append(f"| {t} | {cell('value')} | {cell('raw')} | {cell('heat')} | "
                     f"{row['highways']['median']:.4f} ({row['highways']['min']:.3f}) | {row['within_5pct']}/{n} | "
                     f"{row['value_within_5pct']} / {row['raw_within_5pct']} / {row['heat_within_5pct']} | "
                     f"{row['highways_98pct']}/{n} |")
    fd = result["gradients"]
    if fd:
        lines += ["", f"Gradients vs central differences on {result['fd_grids']} grids of side 8 "
                  f"(agree: relative difference <= {FD_REL:.0%} of max(|numeric|, 1); steps: the base step of "
                  "each argument, then a third and a tenth of it):", "",
                  "| t | argument | agree (base step) | max relative difference | agree at one of the steps | "
                  "max best relative difference | all finite |", "|---|---|---|---|---|---|---|"]
        for t in FD_TEMPERATURES:
            for name in FD_ARGS:
                rows = [r for r in fd if r["t"] == t and r["argument"] == name]
                lines.append(f"| {t} | {name} | {sum(r['agree'] for r in rows)}/{len(rows)} | "
                             f"{max(r['rel_diff'] for r in rows):.2e} | "
                             f"{sum(r['agree_any_step'] for r in rows)}/{len(rows)} | "
                             f"{max(r['best_rel_diff'] for r in rows):.2e} | {all(r['finite'] for r in rows)} |")
    return "\n".join(lines) + "\n"


def plot(result: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ts = [float(t) for t in result["table"]]
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for f in FIELDS:
        med = [max(result["table"][str(t)][f]["median"], 1e-6) for t in ts]
        top = [max(result["table"][str(t)][f]["max"], 1e-6) for t in ts]
        (line,) = ax.loglog(ts, med, "o-", label=f"{f} median")
        ax.loglog(ts, top, "--", color=line.get_color(), alpha=0.5, label=f"{f} max")
    ax.axhline(0.05, color="k", lw=0.8, ls=":")
    ax.set_xlabel("temperature t")
    ax.set_ylabel("max |soft - hard| / max hard")
    ax.set_title(f"Soft fabric convergence, {result['grids']} random grids")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.soft_convergence", description=__doc__.split("\n")[0])
    ap.add_argument("--grids", type=int, default=200, help="random grids (default 200)")
    ap.add_argument("--fd-grids", type=int, default=10, help="grids of side 8 for the gradient checks (default 10)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--results-dir", type=Path, default=RESULTS_DIR)
    ap.add_argument("--no-plot", action="store_true")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    per_grid = []
    for i in range(args.grids):
        scene, params, desc = make_grid(rng)
        per_grid.append(dict(desc, errors=grid_errors(scene, params)))
        if (i + 1) % 20 == 0:
            print(f"{i + 1}/{args.grids} grids", flush=True)
    fd_rng = np.random.default_rng(args.seed + 1)
    gradients, fd_done = [], 0
    while fd_done < args.fd_grids:
        scene, params, _ = make_grid(fd_rng)
        if scene.shape != (8, 8):
            continue
        gradients += gradient_checks(scene, params, fd_rng)
        fd_done += 1
    result = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "host": platform.platform(),
              "grids": args.grids, "seed": args.seed, "fd_grids": args.fd_grids,
              "table": summarise(per_grid), "gradients": gradients,
              "per_grid": [dict(g, errors={str(t): e for t, e in g["errors"].items()}) for g in per_grid]}
    write_results(args.results_dir, "soft_convergence", result, markdown(result))
    if not args.no_plot:
        plot(result, args.results_dir / "soft_convergence.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
