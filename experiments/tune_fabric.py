"""Tune theta_tol, tau_H and the anchor lambda by gradient through the soft fabric, then check the
tuned parameters against the defaults on held-out scenes with the hard episode loop.

    PYTHONPATH=. python experiments/tune_fabric.py [--train 12 --heldout 8 --side 16 --steps 80]

Writes experiments/results/tune_fabric.{json,md,png}: the loss curve (soft objective per step), the
parameter trajectory, and per held-out scene the episode's delivered mass, distance driven, pushes
and delivered per unit driven, default vs tuned. The objective is ``jaxplan.tune.fabric.
soft_efficiency`` (soft delivered mass per unit route length); the held-out metric is the hard
episode's delivered mass per unit distance driven (the job run until done or the push budget).
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


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train", type=int, default=12, help="training scenes")
    ap.add_argument("--heldout", type=int, default=8, help="held-out scenes (other seed)")
    ap.add_argument("--side", type=int, default=16, help="grid side (cells)")
    ap.add_argument("--steps", type=int, default=80, help="Adam steps")
    ap.add_argument("--lr", type=float, default=0.05)
    ap.add_argument("--temperature", type=float, default=0.1)
    ap.add_argument("--spill-lam", type=float, default=0.05)
    ap.add_argument("--max-pushes", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="tune_fabric", help="basename under experiments/results/")
    args = ap.parse_args(argv)

    shape = (args.side, args.side)
    train = tune.random_scenes(args.train, shape, seed=args.seed)
    heldout = tune.random_scenes(args.heldout, shape, seed=10_000 + args.seed)
    config = tune.ObjectiveConfig(temperature=args.temperature, spill_lam=args.spill_lam)
    default = FabricParams()

    t0 = time.perf_counter()
    fit = tune.fit_fabric(train, default, steps=args.steps, learning_rate=args.lr, config=config,
                          on_step=lambda i, r: print(f"step {i:3d}  objective {r['objective']:.4f}  "
                                                     f"theta {r['theta_tol_deg']:.2f}  tau_h {r['tau_h']:.3f}  "
                                                     f"lambda {r['anchor_lambda']:.3f}", flush=True))
    fit_s = time.perf_counter() - t0
    tuned = fit.params
    print("tuned:", {k: getattr(tuned, k) for k in tune.TUNED}, flush=True)

    soft_held = {name: float(np.mean([float(tune.soft_efficiency_jit(s, p, config)) for s in heldout]))
                 for name, p in (("default", default), ("tuned", tuned))}
    t1 = time.perf_counter()
    hard = {name: tune.evaluate_hard(heldout, p, max_pushes=args.max_pushes, spill_lam=args.spill_lam)
            for name, p in (("default", default), ("tuned", tuned))}
    eval_s = time.perf_counter() - t1

    eff = {k: np.array([r["efficiency"] for r in v]) for k, v in hard.items()}
    wins = int(np.sum(eff["tuned"] > eff["default"]))
    summary = dict(
        mean_efficiency={k: float(v.mean()) for k, v in eff.items()},
        mean_delivered={k: float(np.mean([r["delivered"] for r in v])) for k, v in hard.items()},
        mean_driven={k: float(np.mean([r["driven"] for r in v])) for k, v in hard.items()},
        mean_pushes={k: float(np.mean([r["pushes"] for r in v])) for k, v in hard.items()},
        tuned_wins=wins, scenes=len(heldout), soft_objective_heldout=soft_held)
    out = dict(args=vars(args), default={k: getattr(default, k) for k in tune.TUNED},
               tuned={k: getattr(tuned, k) for k in tune.TUNED}, history=fit.history, heldout=hard,
               summary=summary, fit_seconds=fit_s, eval_seconds=eval_s,
               note="timings on a shared 2-core machine (several agents); not benchmarks")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{args.out}.json").write_text(json.dumps(out, indent=1))
    _markdown(out, RESULTS / f"{args.out}.md")
    _plot(out, RESULTS / f"{args.out}.png")
    print(json.dumps(summary, indent=1))
    return out


def _markdown(out: dict, path: Path) -> None:
    s = out["summary"]
    a = out["args"]
    lines = [
        "# Fabric parameters tuned by gradient (soft fabric) vs defaults, held-out hard episodes",
        "",
        f"Command: `PYTHONPATH=. python experiments/tune_fabric.py --train {a['train']} --heldout {a['heldout']} "
        f"--side {a['side']} --steps {a['steps']} --lr {a['lr']} --temperature {a['temperature']} "
        f"--spill-lam {a['spill_lam']} --max-pushes {a['max_pushes']} --seed {a['seed']}`",
        "",
        f"Training: {a['train']} random {a['side']}x{a['side']} scenes (seed {a['seed']}); objective = soft "
        "delivered mass per unit route length (`jaxplan.tune.fabric.soft_efficiency`, temperature "
        f"{a['temperature']}). Held out: {a['heldout']} other scenes, hard `run_episode` (max "
        f"{a['max_pushes']} pushes, spill lam {a['spill_lam']}).",
        "",
        "| | theta_tol (deg) | tau_H | lambda |",
        "|---|---|---|---|",
        "| default | {theta_tol_deg:.2f} | {tau_h:.3f} | {anchor_lambda:.3f} |".format(**out["default"]),
        "| tuned | {theta_tol_deg:.2f} | {tau_h:.3f} | {anchor_lambda:.3f} |".format(**out["tuned"]),
        "",
        f"Soft objective on the training set: {out['history'][0]['objective']:.4f} (step 0) -> "
        f"{out['history'][-1]['objective']:.4f} (step {len(out['history']) - 1}); on the held-out set: "
        f"default {s['soft_objective_heldout']['default']:.4f}, tuned {s['soft_objective_heldout']['tuned']:.4f}.",
        "",
        "| held-out scene | delivered/driven default | tuned | delivered default | tuned | driven default | tuned "
        "| pushes default | tuned |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for i, (d, t) in enumerate(zip(out["heldout"]["default"], out["heldout"]["tuned"])):
        lines.append(f"| {i} | {d['efficiency']:.4f} | {t['efficiency']:.4f} | {d['delivered']:.1f} | "
                     f"{t['delivered']:.1f} | {d['driven']:.1f} | {t['driven']:.1f} | {d['pushes']} | {t['pushes']} |")
    me = s["mean_efficiency"]
    lines += [
        f"| **mean** | **{me['default']:.4f}** | **{me['tuned']:.4f}** | {s['mean_delivered']['default']:.1f} | "
        f"{s['mean_delivered']['tuned']:.1f} | {s['mean_driven']['default']:.1f} | {s['mean_driven']['tuned']:.1f} | "
        f"{s['mean_pushes']['default']:.1f} | {s['mean_pushes']['tuned']:.1f} |",
        "",
        f"Tuned beats default on delivered per unit driven in {s['tuned_wins']} of {s['scenes']} held-out scenes.",
        "",
        f"Fit {out['fit_seconds']:.0f} s, hard evaluation {out['eval_seconds']:.0f} s ({out['note']}).",
        "",
    ]
    path.write_text("\n".join(lines))


def _plot(out: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    hist = out["history"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    axes[0].plot([h["objective"] for h in hist])
    axes[0].set(xlabel="Adam step", ylabel="soft delivered / length", title="training objective (loss = -this)")
    for key in ("theta_tol_deg", "tau_h", "anchor_lambda"):
        v = np.array([h[key] for h in hist])
        axes[1].plot(v / v[0], label=f"{key} (x {v[0]:g})")
    axes[1].set(xlabel="Adam step", ylabel="relative to start", title="parameters")
    axes[1].legend(fontsize=8)
    d = [r["efficiency"] for r in out["heldout"]["default"]]
    t = [r["efficiency"] for r in out["heldout"]["tuned"]]
    x = np.arange(len(d))
    axes[2].bar(x - 0.2, d, 0.4, label="default")
    axes[2].bar(x + 0.2, t, 0.4, label="tuned")
    axes[2].set(xlabel="held-out scene", ylabel="delivered / driven", title="hard episodes")
    axes[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
