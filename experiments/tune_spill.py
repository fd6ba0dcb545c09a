"""Fit the spill model's parameters (lambda, threshold) to synthetic observed routes with optax.

Data: ``jaxplan.tune.spill.synthetic_spill_data`` -- random 8-neighbour grid walks (4..12 waypoints,
0..6 objects picked up per waypoint) observed under known parameters ``TRUE`` (soft threshold,
temperature 0.005 objects), with independent gaussian noise of relative size ``noise`` on each route's
delivered and spilled mass. Fit: ``jaxplan.tune.fit_spill`` from a start 2.5x (lambda) and 3.3x
(threshold) off (Adam in log space, then L-BFGS), at the same temperature.

Reports: the recovery on clean data (target: both parameters within 2%), the error against noise level
(median and max over ``--seeds`` data sets), the loss curves (PNG), JSON and a markdown table.

Examples::

    python -m experiments.tune_spill            # ~1 minute
    python -m experiments.tune_spill --seeds 10 --routes 256
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
from pathlib import Path

import jax
import numpy as np

from jaxplan.transport.spillage import SpillParams
from jaxplan.tune import fit_spill, synthetic_spill_data

RESULTS_DIR = Path(__file__).resolve().parent / "results"
TRUE = SpillParams(lam=0.08, threshold=0.03, temperature=0.005)
START = SpillParams(lam=0.2, threshold=0.1, temperature=TRUE.temperature)
NOISE = (0.0, 0.01, 0.02, 0.05, 0.1, 0.2)
TARGET = 0.02


def _errors(fit) -> tuple[float, float]:
    return (float(fit.params.lam) / TRUE.lam - 1.0, float(fit.params.threshold) / TRUE.threshold - 1.0)


def run(args) -> dict:
    rows, curves = [], {}
    for noise in NOISE:
        errs = []
        for seed in range(args.seeds):
            data = synthetic_spill_data(TRUE, seed=seed, n_routes=args.routes, noise=noise)
            fit = fit_spill(data, START)
            errs.append(_errors(fit))
            if seed == 0:
                curves[noise] = np.asarray(fit.losses).tolist()
        e = np.abs(np.array(errs))
        rows.append({"noise": noise, "lam_err_median": float(np.median(e[:, 0])), "lam_err_max": float(e[:, 0].max()),
                     "threshold_err_median": float(np.median(e[:, 1])), "threshold_err_max": float(e[:, 1].max()),
                     "signed_errors": [list(map(float, x)) for x in errs]})
    clean = rows[0]
    return {"date": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "jax": jax.__version__, "true": {"lam": TRUE.lam, "threshold": TRUE.threshold,
                                             "temperature": TRUE.temperature},
            "start": {"lam": START.lam, "threshold": START.threshold}, "routes": args.routes, "seeds": args.seeds,
            "fit": {"adam_steps": 300, "learning_rate": 0.1, "lbfgs_steps": 50},
            "rows": rows, "loss_curves_seed0": {str(k): v for k, v in curves.items()},
            "clean_within_target": clean["lam_err_max"] <= TARGET and clean["threshold_err_max"] <= TARGET,
            "target": TARGET}


def plot(res: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for noise, curve in res["loss_curves_seed0"].items():
        ax.semilogy(np.maximum(curve, 1e-20), label=f"noise {float(noise):g}")
    ax.axvline(res["fit"]["adam_steps"], color="grey", lw=0.8, ls="--")
    ax.text(res["fit"]["adam_steps"], ax.get_ylim()[1], " L-BFGS", va="top", fontsize=8, color="grey")
    ax.set_xlabel("step (Adam, then L-BFGS)")
    ax.set_ylabel("loss (squared mass error / mean load$^2$)")
    ax.set_title("Spill parameter fit, seed 0")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def markdown(res: dict) -> str:
    t = res["true"]
    lines = ["# Spill parameter fit (jaxplan.tune.fit_spill)", "",
             f"{res['date']}; jax {res['jax']}. True parameters: lambda {t['lam']}, threshold {t['threshold']} objects "
             f"(soft threshold, temperature {t['temperature']}); start lambda {res['start']['lam']}, threshold "
             f"{res['start']['threshold']}. {res['routes']} synthetic routes per data set, {res['seeds']} data sets "
             "(seeds) per noise level; noise = relative standard deviation of gaussian noise on each route's "
             "delivered and spilled mass. Errors are |fitted / true - 1|.", "",
             "| noise | lambda error (median) | lambda error (max) | threshold error (median) "
             "| threshold error (max) |",
             "|---:|---:|---:|---:|---:|"]
    for r in res["rows"]:
        lines.append(f"| {r['noise']:g} | {100 * r['lam_err_median']:.3f}% | {100 * r['lam_err_max']:.3f}% | "
                     f"{100 * r['threshold_err_median']:.3f}% | {100 * r['threshold_err_max']:.3f}% |")
    lines += ["", f"Clean data, both parameters within {100 * res['target']:g}% on every seed: "
              f"**{'met' if res['clean_within_target'] else 'not met'}**. Loss curves: `tune_spill_loss.png`."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m experiments.tune_spill", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=5, help="data sets per noise level")
    p.add_argument("--routes", type=int, default=128, help="routes per data set")
    args = p.parse_args(argv)
    res = run(args)
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    plot(res, RESULTS_DIR / "tune_spill_loss.png")
    text = markdown(res)
    print(text)
    (RESULTS_DIR / "tune_spill.json").write_text(json.dumps(res, indent=1) + "\n")
    (RESULTS_DIR / "tune_spill.md").write_text(text)
    print(f"wrote {RESULTS_DIR / 'tune_spill'}.json, .md and {RESULTS_DIR / 'tune_spill_loss.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
