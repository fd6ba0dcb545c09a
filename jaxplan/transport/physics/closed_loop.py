"""An episode closed through physics: plan on the grid, push in MuJoCo, re-plan from what physics left.

Each push: the fabric is built on the current counts and the episode's planner picks a route
(``plan.plan_episode_tick``, Eq. 6 with the spill model); the grid's own push of that route from the
same counts is its prediction (``execute.execute_push``); the rover drives the route through the
route's particles on the C engine (``check_routes``), and the particles where they came to rest are
rasterised back into counts (``projected_obj``: the grid physics left). The next push is planned
from those counts. It goes on until no source is left, the mass outside the targets is at most
``stop_fraction`` of what it was, or ``max_pushes`` pushes are spent.

Per push it records the mass physics delivered (the target cells' gain on the projected grid) beside
the grid's prediction of the same push from the same counts, and the spilled, left-behind and lost
mass; ``grid_episode`` runs the same loop with the grid's pushes only (no physics), the episode a
plan alone would promise. ``plot_closed_loop`` draws both cumulative curves; ``animate_closed_loop``
writes a GIF of the physical run from above (particles, the rover and the counts, push by push).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import numpy as np

from jaxplan.transport.physics.bridge import check_routes, projected_obj
from jaxplan.transport.physics.model import RoverConfig, rover_qpos_adr

__all__ = ["ClosedLoop", "animate_closed_loop", "grid_episode", "plot_closed_loop", "run_closed_loop"]


class ClosedLoop(NamedTuple):
    """An episode closed through physics (``run_closed_loop``). P pushes, H x W grid.

    obj: f[P + 1, H, W], counts before the first push and after each (physics' projected grid).
    pushes: list of P dicts (python numbers): source, mode, cells, predicted (the grid's delivered mass
      for the push from the same counts), delivered (physics: the target cells' gain), collected,
      spilled, left_behind, lost (objects off the grid).
    frames: list of P arrays f[K, N_p + 1, 2]: world (x, y) of the push's particles and (last row)
      the rover, at K instants of the rollout (for ``animate_closed_loop``).
    stop_reason: "no source", "stop fraction" or "max pushes".
    """

    obj: np.ndarray
    pushes: list
    frames: list
    stop_reason: str

    @property
    def delivered(self) -> np.ndarray:
        """f[P + 1], objects physics has delivered after each push (0 before the first)."""
        return np.concatenate([[0.0], np.cumsum([p["delivered"] for p in self.pushes])])

    @property
    def predicted(self) -> np.ndarray:
        """f[P + 1], the sum of the grid's per-push predictions (each from physics' counts)."""
        return np.concatenate([[0.0], np.cumsum([p["predicted"] for p in self.pushes])])

    @property
    def relative_error(self) -> np.ndarray:
        """f[P], |predicted - delivered| / delivered of the running sums after each push."""
        physics, predicted = self.delivered[1:], self.predicted[1:]
        return np.abs(predicted - physics) / np.maximum(physics, 1e-9)


def _target_mass(scene, obj) -> float:
    return float(np.asarray(obj, np.float64)[np.asarray(scene.target_mask)].sum())


def _outside_mass(scene, obj) -> float:
    return float(np.asarray(obj, np.float64)[~np.asarray(scene.target_mask)].sum())


def _plan(scene, params, ep, spill, evaluator):
    """The episode's next push on ``scene``: ``(plan, route)`` (``route`` with a leading batch of 1)."""
    from jaxplan.transport import build_fabric, default_walk_cap, plan_episode_tick

    fabric = build_fabric(scene, params)
    plan, _ = plan_episode_tick(scene, params, ep, spill, fabric, default_walk_cap(scene.shape), evaluator)
    return plan, jax.tree.map(lambda a: np.asarray(a)[None], plan.route)


def _stop_reason(scene, initial_outside: float, ep, pushes: int, max_pushes: int) -> str | None:
    """The stop rule's parts that need no plan (the last, "no source", is the plan's)."""
    if pushes >= max_pushes:
        return "max pushes"
    if _outside_mass(scene, scene.obj) <= float(ep.stop_fraction) * initial_outside:
        return "stop fraction"
    return None


def _frames(check, n_frames: int) -> np.ndarray:
    """f[K, N_p + 1, 2]: the push's particles and the rover at ``n_frames`` instants of its rollout."""
    world, qpos = check.world, np.asarray(check.trajectory.qpos[0])
    n_p = check.particle_cells[0].shape[0]
    ticks = np.unique(np.linspace(0, qpos.shape[0] - 1, n_frames).round().astype(int))
    particles = world.particle_xyz(qpos[ticks])[:, :n_p, :2]
    adr = int(rover_qpos_adr(world)[0])
    rover = qpos[ticks][:, adr: adr + 2][:, None, :]
    return np.concatenate([particles, rover], 1)


def _drive(scene, params, spill, episode, max_pushes: int, push, progress: bool = False):
    """The loop both episodes share: plan on the current counts, ``push(scene, plan, route, spill,
    evaluator) -> (counts after f[H, W], record dict)``, carry on from the counts after, until the stop
    rule. Returns ``(records, obj f[P + 1, H, W], stop_reason)``; each record gains ``delivered``, the
    target cells' gain."""
    from tqdm.auto import tqdm

    from jaxplan.transport import EpisodeParams, FabricParams
    from jaxplan.transport.spillage import LEARNED_FIT, evaluator_for

    params = FabricParams() if params is None else params
    spill = LEARNED_FIT if spill is None else spill
    ep = EpisodeParams() if episode is None else episode
    if not isinstance(max_pushes, (int, np.integer)) or isinstance(max_pushes, bool) or max_pushes < 1:
        raise ValueError(f"max_pushes: must be an int >= 1; got {max_pushes!r}.")
    evaluator = evaluator_for(spill)
    initial_outside = _outside_mass(scene, scene.obj)
    obj, records = [np.asarray(scene.obj, np.float64)], []
    with tqdm(total=int(max_pushes), desc="pushes in physics", unit="push", disable=not progress) as bar:
        while True:
            reason = _stop_reason(scene, initial_outside, ep, len(records), int(max_pushes))
            if reason is None:
                plan, route = _plan(scene, params, ep, spill, evaluator)
                reason = None if bool(plan.has_source) else "no source"
            if reason is not None:
                return records, np.stack(obj), reason
            after, record = push(scene, plan, route, spill, evaluator)
            record["delivered"] = _target_mass(scene, after) - _target_mass(scene, scene.obj)
            records.append(record)
            scene = scene.with_obj(np.asarray(after, np.float32))
            obj.append(np.asarray(after, np.float64))
            bar.update()


def run_closed_loop(scene, params=None, spill=None, episode=None, *, max_pushes: int = 15,
                    config: RoverConfig | None = None, frames_per_push: int = 6,
                    progress: bool = False) -> ClosedLoop:
    """Plan, push in MuJoCo (C engine), rasterise, re-plan: ``max_pushes`` pushes at most (module
    docstring). spill: the model the planner selects and predicts with (default ``LEARNED_FIT``, the
    fit to this rover); episode: ``EpisodeParams`` (its ``stop_fraction``, ``source_rule``,
    ``rearrange_margin``, ``reselect``); config: the rover (``RoverConfig()``)."""
    from jaxplan.transport import execute_push

    frames = []

    def physics_push(scene, plan, route, spill, evaluator):
        _, push = execute_push(scene, plan.route, spill, evaluator)
        check = check_routes(scene, route, config=config, spill=spill, evaluator=evaluator)
        after, lost = projected_obj(scene, check, 0)
        frames.append(_frames(check, frames_per_push))
        out = check.outcome
        cells = np.asarray(plan.route.cells)[: int(plan.route.n_cells)]
        return after, {"source": [int(x) for x in np.asarray(plan.source)], "mode": int(plan.mode),
                       "cells": cells.tolist(), "predicted": float(push.delivered),
                       "collected": float(np.asarray(out.collected)[0]),
                       "spilled": float(np.asarray(out.spilled)[0]),
                       "left_behind": float(np.asarray(out.left_behind)[0]), "lost": float(lost)}

    pushes, obj, reason = _drive(scene, params, spill, episode, max_pushes, physics_push, progress)
    return ClosedLoop(obj, pushes, frames, reason)


def grid_episode(scene, params=None, spill=None, episode=None, *, max_pushes: int = 15) -> np.ndarray:
    """f[P + 1]: the cumulative delivered mass of the same loop pushed on the grid only (the episode
    the plan alone predicts), with the same planner, spill model and stop rule."""
    from jaxplan.transport import execute_push

    def grid_push(scene, plan, route, spill, evaluator):
        return execute_push(scene, plan.route, spill, evaluator)[0], {}

    pushes, _, _ = _drive(scene, params, spill, episode, max_pushes, grid_push)
    return np.concatenate([[0.0], np.cumsum([p["delivered"] for p in pushes])])


def plot_closed_loop(loop: ClosedLoop, grid_only: np.ndarray | None = None, title: str = ""):
    """Cumulative delivered mass after each push: physics, the grid's per-push predictions from
    physics' counts, and (if given) the grid-only episode. Returns the figure."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6))
    x = np.arange(len(loop.obj))
    ax.plot(x, loop.delivered, "o-", label="physics (MuJoCo)")
    ax.plot(x, loop.predicted, "s--", label="predicted, push by push")
    if grid_only is not None:
        ax.plot(np.arange(len(grid_only)), grid_only, ":", label="grid-only episode")
    ax.set_xlabel("push")
    ax.set_ylabel("delivered (objects)")
    ax.set_title(title or "episode closed through physics")
    ax.legend()
    fig.tight_layout()
    return fig


def animate_closed_loop(scene, loop: ClosedLoop, path, *, fps: int = 6, dpi: int = 80) -> None:
    """A GIF (or, by suffix, a video) of the physical run from above: for each push, the counts
    before it (grey scale), its particles (orange) and the rover (blue) through the rollout."""
    import matplotlib.pyplot as plt

    from jaxplan.core import save_animation

    h, w = scene.shape
    s = float(np.asarray(scene.cell_size))
    ox, oy = (float(v) for v in np.asarray(scene.origin))
    extent = (ox, ox + w * s, oy, oy + h * s)
    index = [(k, i) for k, f in enumerate(loop.frames) for i in range(f.shape[0])]
    fig, ax = plt.subplots(figsize=(4.5, 4.5 * h / w + 0.4))
    image = ax.imshow(loop.obj[0], origin="lower", extent=extent, cmap="Greys", vmin=0,
                      vmax=max(float(loop.obj.max()), 1.0))
    ax.contour(np.asarray(scene.target_mask, float), levels=[0.5], colors="green", extent=extent, origin="lower")
    particles = ax.scatter([], [], s=6, c="tab:orange")
    rover = ax.scatter([], [], s=60, c="tab:blue", marker="s")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])

    def draw(n):
        k, i = index[n]
        image.set_data(loop.obj[k])
        particles.set_offsets(loop.frames[k][i, :-1])
        rover.set_offsets(loop.frames[k][i, -1:])
        ax.set_title(f"push {k + 1}: physics delivered {loop.pushes[k]['delivered']:.0f}, "
                     f"predicted {loop.pushes[k]['predicted']:.1f}", fontsize=9)
        return image, particles, rover

    save_animation(fig, draw, max(len(index), 1), path, fps=fps, dpi=dpi)
