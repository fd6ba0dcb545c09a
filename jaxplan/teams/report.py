"""The paper scenario end to end: simulate it, draw Fig. 6 and summarise it (``jaxplan teams``).

``plot_performance`` draws the paper's Fig. 6 from a ``Trace``: per team, predicted (Eq. 1) and real
(Eq. 2) performance over time, with the number of trucks in the team on a second axis. It never
selects a matplotlib backend (the CLI does).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from jaxplan.teams.generators import PAPER, paper_config, paper_scenario
from jaxplan.teams.params import STRATEGIES

__all__ = ["check_paper_options", "plot_performance", "run_paper", "summarize"]

_PRED, _REAL, _TRUCKS = "#2563eb", "#dc2626", "#6b7280"


def plot_performance(trace, dt: float = 1.0, events=(), deadline: float | None = None):
    """Fig. 6: one panel per team; ``events`` are ``(time_s, label)`` marked with dotted lines."""
    import matplotlib.pyplot as plt

    r_pred, r_real = np.asarray(trace.r_pred), np.asarray(trace.r_real)
    n = np.asarray(trace.n_trucks)
    steps, m = r_pred.shape
    t = np.arange(steps) * dt
    fig, axes = plt.subplots(m, 1, figsize=(8, 2.8 * m), sharex=True, squeeze=False)
    for i, ax in enumerate(axes[:, 0]):
        ax.plot(t, r_pred[:, i], color=_PRED, lw=1.5, label="predicted (Eq. 1)")
        ax.plot(t, r_real[:, i], color=_REAL, lw=1.0, label="real (Eq. 2)")
        ax.set_ylabel("performance [kg/s]")
        ax.set_title(f"team {i + 1}")
        ax.set_ylim(bottom=0)
        twin = ax.twinx()
        twin.step(t, n[:, i], where="post", color=_TRUCKS, lw=1.0, ls="--", label="trucks")
        twin.set_ylabel("trucks in team")
        twin.set_ylim(0, max(int(n.max()), 1) + 1)
        for when, label in events:
            ax.axvline(when, color="k", ls=":", lw=0.8)
            ax.text(when, ax.get_ylim()[1] * 0.95, f" {label}", fontsize=8, va="top")
        if deadline is not None:
            ax.axvline(deadline, color="k", lw=0.8)
            ax.text(deadline, ax.get_ylim()[1] * 0.95, " deadline", fontsize=8, va="top")
        lines = ax.get_legend_handles_labels()
        extra = twin.get_legend_handles_labels()
        ax.legend(lines[0] + extra[0], lines[1] + extra[1], loc="upper left", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    return fig


def _timeline(counts: np.ndarray, dt: float) -> list:
    """``[[time_s, trucks], ...]``: the team size at t = 0 and at every change."""
    change = np.flatnonzero(np.diff(counts)) + 1
    return [[0.0, int(counts[0])]] + [[float(s * dt), int(counts[s])] for s in change]


def _num(x) -> float | None:
    x = float(x)
    return None if math.isnan(x) else round(x, 3)


def summarize(params, result, trace, strategy: str) -> dict:
    """A JSON-ready dict: per team its clear and finishing times, delivered mass, truck timeline."""
    dt = float(np.asarray(params.dt))
    n = np.asarray(trace.n_trucks)
    teams = []
    for i in range(n.shape[1]):
        teams.append({
            "team": i + 1,
            "initial_mass_kg": float(np.asarray(params.mass)[i]),
            "clear_time_s": _num(np.asarray(result.clear_time)[i]),
            "finishing_time_s": _num(np.asarray(result.finish_time)[i]),
            "delivered_kg": round(float(np.asarray(result.delivered)[i]), 3),
            "lost_kg": round(float(np.asarray(result.lost)[i]), 3),
            "max_trucks": int(np.asarray(result.max_team)[i]),
            "truck_count_timeline": _timeline(n[:, i], dt),
        })
    return {
        "scenario": "paper (Endo et al., Section III, Table III)",
        "strategy": strategy,
        "deadline_s": float(np.asarray(params.deadline)),
        "deadline_met": bool(np.asarray(result.met)),
        "deadline_rule": "met = every loading site cleared (empty, last loading over) by the deadline",
        "all_delivered_s": _num(result.finish_all),
        "peak_trucks": int(np.asarray(result.peak_trucks)),
        "truck_seconds": round(float(np.asarray(result.truck_seconds)), 3),
        "dt_s": dt,
        "teams": teams,
    }


def check_paper_options(strategy: str, v_after: float, deadline: float, seed: int, steps: int) -> None:
    """Raise ``ValueError`` naming the option (its CLI flag) when one is out of range."""
    if strategy not in STRATEGIES:
        raise ValueError(f"--strategy: must be one of {', '.join(STRATEGIES)}; got {strategy!r}.")
    if not (math.isfinite(v_after) and v_after > 0):
        raise ValueError(f"--v-after: the velocity after the drop must be a positive number of m/s; "
                         f"got {v_after!r}.")
    if not (math.isfinite(deadline) and deadline > 0):
        raise ValueError(f"--deadline: must be a positive number of seconds; got {deadline!r}.")
    if seed < 0:
        raise ValueError(f"--seed: must be >= 0; got {seed}.")
    if steps < 1:
        raise ValueError(f"--steps: must be >= 1; got {steps}.")


def _plain_write(path, callback) -> None:
    with open(path, "wb") as fh:
        callback(fh)


def run_paper(out_dir, strategy: str = "performance", seed: int = 0,
              v_after: float = PAPER["v_after"], deadline: float = PAPER["deadline"],
              steps: int = 1200, write=None) -> dict:
    """Simulate the paper scenario, write ``out_dir/fig6.png`` and ``out_dir/summary.json``.

    ``write(path, callback)`` writes one file (the CLI passes its atomic writer); bad options raise
    ``ValueError`` naming the option, a failed write raises ``ValueError`` naming ``--out``.
    Returns the summary dict.
    """
    import matplotlib.pyplot as plt

    from jaxplan.teams.sim import simulate_site

    check_paper_options(strategy, v_after, deadline, seed, steps)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out: {str(out)!r} exists and is not a directory; pass a directory.")
    try:  # before the simulation, so that an unusable directory fails fast
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out: could not create {str(out)!r} ({exc.strerror or exc}).") from None
    params = paper_scenario(seed=seed, v_after=v_after, deadline=deadline)
    result, trace = simulate_site(paper_config(strategy, record=True, n_steps=steps), params)
    summary = summarize(params, result, trace, strategy)
    fig = plot_performance(trace, float(params.dt), events=[(PAPER["v_drop_t"], "velocity drop")],
                           deadline=deadline)
    png, js = out / "fig6.png", out / "summary.json"
    summary["outputs"] = {"figure": str(png), "summary": str(js)}
    write = write or _plain_write
    try:
        write(png, lambda fh: fig.savefig(fh, format="png", dpi=120))
        text = json.dumps(summary, indent=2) + "\n"
        write(js, lambda fh: fh.write(text.encode()))
    except OSError as exc:
        raise ValueError(f"--out: could not write into {str(out)!r} ({exc.strerror or exc}).") from None
    finally:
        plt.close(fig)
    return summary
