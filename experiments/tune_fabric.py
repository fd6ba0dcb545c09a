"""Tune theta_tol, tau_H and the anchor lambda by gradient through the soft fabric, then check the
tuned parameters against the defaults on held-out scenes with the hard episode loop.

    python -m experiments.tune_fabric [--train 12 --heldout 16 --side 16 --steps 80 --seeds 0 1 2]

For every seed and every objective variant: fit on ``--train`` random scenes (that seed), evaluate
default and tuned parameters on ``--heldout`` other scenes with ``jaxplan.run_episode``. Variants
(``jaxplan.tune.fabric.ObjectiveConfig``):

- ``job``: soft delivered mass per unit driven over the whole job (approach drive charged,
  harmonic aggregate) -- the objective ``fit_fabric`` uses by default;
- ``route``: the first objective we tried, soft delivered per unit of route length averaged over
  sources (no approach, arithmetic aggregate); kept as the ablation that shows why ``job`` is needed.

Writes experiments/results/tune_fabric.{json,md,png}: loss curves, parameter trajectories, per
held-out scene the episode's delivered mass, distance driven, pushes and delivered per unit driven.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from jaxplan import FabricParams
from jaxplan.tune import fabric as tune

RESULTS = Path(__file__).resolve().parent / "results"
VARIANTS = {"job": dict(aggregate="job", approach=True), "route": dict(aggregate="source", approach=False)}


def run_one(seed: int, variant: str, args) -> dict:
    """Fit on the training scenes of ``seed`` with objective ``variant``; hard-evaluate on held-out."""
    shape = (args.side, args.side)
    train = tune.random_scenes(args.train, shape, seed=seed)
    heldout = tune.random_scenes(args.heldout, shape, seed=10_000 + seed)
    config = tune.ObjectiveConfig(temperature=args.temperature, spill_lam=args.spill_lam, **VARIANTS[variant])
    default = FabricParams()
    t0 = time.perf_counter()
    fit = tune.fit_fabric(train, default, steps=args.steps, learning_rate=args.lr, config=config,
                          tune_spill=args.tune_spill, on_step=lambda i, r: i % 10 == 0 and print(
                              f"seed {seed} {variant:5s} step {i:3d}  objective {r['objective']:.4f}  theta "
                              f"{r['theta_tol_deg']:.2f}  tau_h {r['tau_h']:.3f}  lambda {r['anchor_lambda']:.3f}",
                              flush=True))
    fit_s = time.perf_counter() - t0
    tuned = fit.params
    t1 = time.perf_counter()
    hard = {name: tune.evaluate_hard(heldout, p, max_pushes=args.max_pushes, spill_lam=args.spill_lam, plan_lam=lam)
            for name, p, lam in (("default", default, None), ("tuned", tuned, fit.spill_lam))}
    eval_s = time.perf_counter() - t1
    eff = {k: np.array([r["efficiency"] for r in v]) for k, v in hard.items()}
    summary = dict(
        mean_efficiency={k: float(v.mean()) for k, v in eff.items()},
        mean_delivered={k: float(np.mean([r["delivered"] for r in v])) for k, v in hard.items()},
        mean_driven={k: float(np.mean([r["driven"] for r in v])) for k, v in hard.items()},
        mean_pushes={k: float(np.mean([r["pushes"] for r in v])) for k, v in hard.items()},
        tuned_wins=int(np.sum(eff["tuned"] > eff["default"])), scenes=len(heldout))
    row = dict(seed=seed, variant=variant, default={k: getattr(default, k) for k in tune.TUNED},
               tuned={k: float(getattr(tuned, k)) for k in tune.TUNED}, tuned_plan_spill_lam=fit.spill_lam,
               history=fit.history, heldout=hard,
               summary=summary, fit_seconds=fit_s, eval_seconds=eval_s)
    me = summary["mean_efficiency"]
    print(f"seed {seed} {variant:5s}: tuned {row['tuned']}  delivered/driven default {me['default']:.4f} "
          f"tuned {me['tuned']:.4f}  wins {summary['tuned_wins']}/{len(heldout)}", flush=True)
    return row


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m experiments.tune_fabric", description=__doc__.splitlines()[0])
    ap.add_argument("--train", type=int, default=12, help="training scenes per seed")
    ap.add_argument("--heldout", type=int, default=16, help="held-out scenes per seed (seed + 10000)")
    ap.add_argument("--side", type=int, default=16, help="grid side (cells)")
    ap.add_argument("--steps", type=int, default=80, help="Adam steps")
    ap.add_argument("--lr", type=float, default=0.05)
    ap.add_argument("--temperature", type=float, default=0.5)
    ap.add_argument("--spill-lam", type=float, default=0.05)
    ap.add_argument("--max-pushes", type=int, default=200)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--tune-spill", action="store_true",
                    help="also tune the planner's spill lambda (Eq. 6 through the soft fabric); the world's stays "
                         "--spill-lam")
    ap.add_argument("--out", default="tune_fabric", help="basename under experiments/results/")
    args = ap.parse_args(argv)

    runs = [run_one(seed, variant, args) for variant in args.variants for seed in args.seeds]
    out = dict(args=vars(args), runs=runs,
               note="timings on a shared 2-core machine; not benchmarks")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{args.out}.json").write_text(json.dumps(out, indent=1))
    _markdown(out, RESULTS / f"{args.out}.md")
    _plot(out, RESULTS / f"{args.out}.png")
    return out


def _markdown(out: dict, path: Path) -> None:
    a = out["args"]
    lines = [
        "# Fabric parameters tuned by gradient (soft fabric) vs defaults, held-out hard episodes",
        "",
        f"Command: `python -m experiments.tune_fabric --train {a['train']} --heldout {a['heldout']} "
        f"--side {a['side']} --steps {a['steps']} --lr {a['lr']} --temperature {a['temperature']} "
        f"--spill-lam {a['spill_lam']} --max-pushes {a['max_pushes']} --seeds {' '.join(map(str, a['seeds']))} "
        f"--variants {' '.join(a['variants'])}{' --tune-spill' if a.get('tune_spill') else ''}`",
        "",
        f"Per seed: fit on {a['train']} random {a['side']}x{a['side']} scenes, evaluate on {a['heldout']} other "
        f"scenes (seed + 10000) with the hard `run_episode` (max {a['max_pushes']} pushes, spill lam "
        f"{a['spill_lam']}); metric = delivered mass per unit distance driven (approach + pushed route). "
        "Objective variants: `job` = soft delivered per unit driven over the whole job (approach charged, "
        "harmonic aggregate; the default of `fit_fabric`); `route` = soft delivered per unit route length, "
        "arithmetic mean over sources (the first objective, kept as the ablation).",
        "",
        "| objective | seed | tuned theta_tol (deg) | tau_H | lambda | planner spill lambda | soft objective "
        "step 0 -> last | delivered/driven default | tuned | change | tuned wins | pushes default | tuned |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in out["runs"]:
        s, t, h = r["summary"], r["tuned"], r["history"]
        me = s["mean_efficiency"]
        lines.append(
            f"| {r['variant']} | {r['seed']} | {t['theta_tol_deg']:.1f} | {t['tau_h']:.3f} "
            f"| {t['anchor_lambda']:.3f} | "
            f"{'-' if r.get('tuned_plan_spill_lam') is None else format(r['tuned_plan_spill_lam'], '.4f')} | "
            f"{h[0]['objective']:.3f} -> {h[-1]['objective']:.3f} | {me['default']:.4f} | {me['tuned']:.4f} | "
            f"{100 * (me['tuned'] / me['default'] - 1):+.1f}% | {s['tuned_wins']}/{s['scenes']} | "
            f"{s['mean_pushes']['default']:.1f} | {s['mean_pushes']['tuned']:.1f} |")
    lines += ["", "Defaults: theta_tol 60 deg, tau_H 0.5, lambda 1.", ""]
    for r in out["runs"]:
        lines += [f"## {r['variant']}, seed {r['seed']}: per held-out scene", "",
                  "| scene | delivered/driven default | tuned | delivered default | tuned | driven default | tuned "
                  "| pushes default | tuned |", "|---|---|---|---|---|---|---|---|---|"]
        for i, (d, t) in enumerate(zip(r["heldout"]["default"], r["heldout"]["tuned"])):
            lines.append(f"| {i} | {d['efficiency']:.4f} | {t['efficiency']:.4f} | {d['delivered']:.1f} | "
                         f"{t['delivered']:.1f} | {d['driven']:.1f} | {t['driven']:.1f} | {d['pushes']} | "
                         f"{t['pushes']} |")
        lines += ["", f"Fit {r['fit_seconds']:.0f} s, hard evaluation {r['eval_seconds']:.0f} s ({out['note']}).", ""]
    path.write_text("\n".join(lines))


def _plot(out: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = out["runs"]
    fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
    for r in runs:
        style = "-" if r["variant"] == "job" else "--"
        axes[0].plot([h["objective"] for h in r["history"]], style, label=f"{r['variant']} seed {r['seed']}")
        axes[1].plot([h["theta_tol_deg"] for h in r["history"]], style, label=f"{r['variant']} seed {r['seed']}")
    axes[0].set(xlabel="Adam step", ylabel="soft objective", title="training objective (loss = -this)")
    axes[0].legend(fontsize=7)
    axes[1].set(xlabel="Adam step", ylabel="theta_tol (deg)", title="cone half-angle during the fit")
    labels = [f"{r['variant']}\nseed {r['seed']}" for r in runs]
    d = [r["summary"]["mean_efficiency"]["default"] for r in runs]
    t = [r["summary"]["mean_efficiency"]["tuned"] for r in runs]
    x = np.arange(len(runs))
    axes[2].bar(x - 0.2, d, 0.4, label="default")
    axes[2].bar(x + 0.2, t, 0.4, label="tuned")
    axes[2].set_xticks(x, labels, fontsize=7)
    axes[2].set(ylabel="mean delivered / driven", title="held-out hard episodes")
    axes[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
