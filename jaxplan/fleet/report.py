"""A fleet run's report: its numbers (summary, trajectory, pushes), a figure and an animation.

Everything here reads a :class:`jaxplan.fleet.run.FleetRun` and nothing else. The files
:func:`write_fleet_outputs` writes into a run's output folder (``FLEET_OUTPUTS``):

- ``summary.json``, :func:`summary_of`: the run in numbers (the scene's name, mass, mass cut off
  from every target, T50 / T90, pushes and idle time per rover, planning time per event, conflicts,
  stop reason);
- ``trajectory.npz``, :func:`trajectory_arrays`: ``pos i32[T+1, N, 2]`` (row, col), ``delivered
  f64[T+1]``, ``outside f64[T+1]`` (objects), ``initial_mass f64[]``, the counts ``obj_initial`` and
  ``obj_final`` (f32[H, W]) and ``convention`` (a string: cells are (row, col), rows = y);
- ``pushes.json``, :func:`pushes_records`: one record per push;
- ``fleet.png``, :func:`plot_fleet`: four panels, mass over time with T50 / T90 labelled, the
  initial piles with the targets and the rovers' starts, the traffic (:func:`traffic_counts`: how
  often each cell was driven) and the final counts with the rovers' final cells;
- ``fleet.gif``, :func:`animate_fleet`: the mass (counts per cell), targets, every rover and its
  current route, step by step (from ``run.frames``; only when the run was recorded).

Both pictures draw the scene's blocked cells (``scene.blocked``) as solid dark-grey squares, like
every scene figure of :mod:`jaxplan.transport.viz` (``draw_blocked``).

T50 and T90 are the first step at which the mass delivered since the start (``delivered[t] -
delivered[0]``) reaches 50% / 90% of the mass that started outside the targets; None if it never
does. Plots follow :mod:`jaxplan.transport.viz` (rows = y, ``origin="lower"``, world units) and, like
it, never select a matplotlib backend.
"""
from __future__ import annotations

import math

import numpy as np

from jaxplan.core import save_animation
from jaxplan.fleet.run import FleetRun
from jaxplan.transport import PALETTE, blocked_handle, blocked_of, cell_edges, draw_blocked, finite_max, polygon_rings

__all__ = ["DEFAULT_MAX_FRAMES", "FIGURE_PANELS", "FLEET_OUTPUTS", "MASS_CMAP", "TRAFFIC_CMAP", "TRAJECTORY_CONVENTION",
           "animate_fleet", "frame_steps", "plot_fleet", "pushes_records", "summary_of", "t_fraction",
           "traffic_counts", "trajectory_arrays", "write_fleet_outputs"]

FLEET_OUTPUTS = ("summary.json", "trajectory.npz", "pushes.json", "fleet.png", "fleet.gif")

# Rover labels (their index) are drawn up to this many rovers; beyond, the markers alone.
_LABEL_MAX_ROVERS = 16
# Animation frames at most, by default: a long run is subsampled evenly (the last step always shown).
DEFAULT_MAX_FRAMES = 240
# fleet.png's panels, row by row; each Axes carries its name as its gid.
FIGURE_PANELS = ("mass", "start", "traffic", "final")
# Colour maps: the counts per cell (pale when empty: rovers, routes, targets and blocked cells stand
# out over it) and the traffic (cells never driven are left white).
MASS_CMAP = "YlOrBr"
TRAFFIC_CMAP = "RdPu"
# Target cells are tinted (PALETTE["target"], see-through) rather than put on the counts' scale: the
# delivered mass piles up there and would flatten the colours of the rest.
_TARGET_TINT = (0.231, 0.510, 0.965, 0.25)


# --------------------------------------------------------------------------------------------------
# Numbers


def _float_or_none(x) -> float | None:
    """A JSON-safe float: None for NaN / inf (JSON has neither)."""
    x = float(x)
    return x if math.isfinite(x) else None


def _check_run(run: FleetRun) -> tuple[int, int]:
    """(T, N) of ``run`` after checking the arrays agree with them; ValueError naming the field."""
    t, n = int(run.steps), int(run.n_rovers)
    pos = np.asarray(run.pos)
    if pos.shape != (t + 1, n, 2):
        raise ValueError(f"FleetRun.pos: shape {pos.shape}, expected (steps + 1, n_rovers, 2) = {(t + 1, n, 2)}.")
    for field in ("delivered", "outside"):
        shape = np.shape(getattr(run, field))
        if shape != (t + 1,):
            raise ValueError(f"FleetRun.{field}: shape {shape}, expected (steps + 1,) = ({t + 1},).")
    for field in ("rover_pushes", "idle_steps"):
        shape = np.shape(getattr(run, field))
        if shape != (n,):
            raise ValueError(f"FleetRun.{field}: shape {shape}, expected (n_rovers,) = ({n},).")
    return t, n


def t_fraction(run: FleetRun, fraction: float) -> int | None:
    """The first step t with ``delivered[t] - delivered[0] >= fraction * initial_outside``, or None.

    fraction in [0, 1]: 0.5 gives T50, 0.9 gives T90 (steps; 0 = already at the start).
    """
    gain = np.asarray(run.delivered, np.float64) - float(run.delivered[0])
    hit = np.nonzero(gain >= fraction * float(run.initial_outside))[0]
    return int(hit[0]) if hit.size else None


def summary_of(run: FleetRun) -> dict:
    """The run in numbers, JSON-ready (summary.json). Mass in objects, times in steps unless named.

    delivered: mass brought into the targets during the run (``delivered[T] - delivered[0]``);
    spilled: sum of the pushes' spills (spilled mass stays on the site and may be pushed again);
    remaining: mass outside the targets at the end. idle_fraction: ``idle_steps / steps`` per rover.
    scene: the scene's name (``FleetRun.scene_name``), None without one. unreachable_mass: objects on
    free cells cut off from every target by blocked cells (``Scene.unreachable_mass``): never pushed.
    delivered_per_rover_step: delivered / (N * T). step_ms, plan_ms, refresh_ms: wall ms over every
    step, ``{"median", "p95"}`` (None without steps): the whole step, everything but the fabric's
    refresh, and the refresh (0 in steps where no push ended). full_build_ms: one warm full build of
    the site's initial fabric, measured in the same process (None when not measured). dropped: tasks
    dropped as unreachable; made_way: parked rovers sent out of a task's footprint. tasks_planned: the
    tasks the coordinated assignments planned, in all; plan_ms_planning / plan_ms_not_planning:
    ``plan_ms`` over the steps that planned a task and over the others (``{"median", "p95"}``).
    """
    t, n = _check_run(run)
    delivered = float(run.delivered[-1]) - float(run.delivered[0])
    return {
        "scene": run.scene_name if run.scene_name is not None else getattr(run.scene, "name", None),
        "grid": list(run.scene.shape),
        "n_rovers": n,
        "strategy": str(run.strategy),
        "steps": t,
        "initial_mass": float(run.initial_mass),
        "initial_outside": float(run.initial_outside),
        "unreachable_mass": float(np.asarray(run.scene.unreachable_mass)),
        "delivered": delivered,
        "spilled": float(sum(float(p["spilled"]) for p in run.pushes)),
        "remaining": float(run.outside[-1]),
        "T50": t_fraction(run, 0.5),
        "T90": t_fraction(run, 0.9),
        "pushes": len(run.pushes),
        "pushes_per_rover": [int(v) for v in np.asarray(run.rover_pushes)],
        "idle_fraction": [float(v) / max(t, 1) for v in np.asarray(run.idle_steps)],
        "delivered_per_rover_step": delivered / max(n * t, 1),
        "step_ms": _median_p95(run.step_ms),
        "plan_ms": _median_p95(run.plan_ms),
        "refresh_ms": _median_p95(run.refresh_ms),
        "full_build_ms": None if run.full_build_ms is None else _float_or_none(run.full_build_ms),
        "dropped": int(run.dropped),
        "made_way": int(run.made_way),
        "tasks_planned": int(sum(run.tasks_planned)),
        "plan_ms_planning": _median_p95([ms for ms, k in zip(run.plan_ms, run.tasks_planned) if k > 0]),
        "plan_ms_not_planning": _median_p95([ms for ms, k in zip(run.plan_ms, run.tasks_planned) if k == 0]),
        "conflicts": int(run.conflicts),
        "stop_reason": str(run.stop_reason),
        "message": str(run.message),
    }


def _median_p95(ms) -> dict:
    """``{"median", "p95"}`` of a list of milliseconds (None for an empty one)."""
    values = np.asarray(ms, np.float64)
    if values.size == 0:
        return {"median": None, "p95": None}
    return {"median": _float_or_none(np.median(values)), "p95": _float_or_none(np.percentile(values, 95))}


TRAJECTORY_CONVENTION = "cells are (row, col); rows = y, columns = x"


def trajectory_arrays(run: FleetRun) -> dict:
    """The arrays of trajectory.npz: ``pos i32[T+1, N, 2]`` (row, col), ``delivered f64[T+1]`` (mass
    inside the targets), ``outside f64[T+1]`` (mass outside), ``initial_mass f64[]`` (objects),
    ``obj_initial`` and ``obj_final`` (f32[H, W], the counts at the start and the end; rows = y) and
    ``convention`` (a string scalar, ``TRAJECTORY_CONVENTION``)."""
    _check_run(run)
    grids = {"obj_initial": run.scene.obj, "obj_final": run.final_scene.obj}
    for field, obj in grids.items():
        if np.shape(obj) != tuple(run.scene.shape):
            raise ValueError(f"FleetRun.{'scene' if field == 'obj_initial' else 'final_scene'}: counts of shape "
                             f"{np.shape(obj)}, expected the grid's {tuple(run.scene.shape)}.")
    return {
        "pos": np.asarray(run.pos, np.int32),
        "delivered": np.asarray(run.delivered, np.float64),
        "outside": np.asarray(run.outside, np.float64),
        "initial_mass": np.asarray(run.initial_mass, np.float64),
        **{field: np.asarray(obj, np.float32) for field, obj in grids.items()},
        "convention": np.asarray(TRAJECTORY_CONVENTION),
    }


def pushes_records(run: FleetRun) -> list:
    """pushes.json: one JSON-ready dict per push, in the order they were applied: index, rover,
    first_step, last_step, cells ``[[row, col], ...]``, collected, delivered, spilled (objects), mode."""
    return [{
        "index": i,
        "rover": int(p["rover"]),
        "first_step": int(p["first_step"]),
        "last_step": int(p["last_step"]),
        "cells": [[int(r), int(c)] for r, c in np.asarray(p["cells"]).reshape(-1, 2)],
        "collected": float(p["collected"]),
        "delivered": float(p["delivered"]),
        "spilled": float(p["spilled"]),
        "mode": str(p.get("mode", "deliver")),
    } for i, p in enumerate(run.pushes)]


# --------------------------------------------------------------------------------------------------
# Pictures


def _frame_of(scene):
    """(x0, y0, s, extent, centre) of ``scene``: ``centre(cells i[k, 2]) -> f64[k, 2]`` world (x, y)."""
    h, w = scene.shape
    s = float(np.asarray(scene.cell_size))
    x0, y0 = (float(v) for v in np.asarray(scene.origin))
    extent = (x0, x0 + w * s, y0, y0 + h * s)

    def centre(cells):
        cells = np.asarray(cells, np.float64).reshape(-1, 2)
        return np.stack([x0 + (cells[:, 1] + 0.5) * s, y0 + (cells[:, 0] + 0.5) * s], -1)

    return x0, y0, s, extent, centre


def _finite(values) -> np.ndarray:
    """``values`` as f64 with NaN in place of every non-finite value (left blank, never on a colour scale)."""
    values = np.asarray(values, np.float64)
    return np.where(np.isfinite(values), values, np.nan)


def _rover_colors(n: int):
    """One colour per rover, hues from green through blue to magenta: clear of the counts' yellows and
    browns (``MASS_CMAP``)."""
    import matplotlib.colors as mcolors

    hues = 0.3 + 0.62 * np.arange(n) / max(n - 1, 1) if n > 1 else np.array([0.6])
    return [mcolors.hsv_to_rgb((h, 0.85, 1.0)) for h in hues]


def _blocked_cells(run: FleetRun) -> np.ndarray:
    """``bool[H, W]``: the cells blocked in the run's scene or its final scene (the same mask, as a
    run never changes its geometry; a scene without blocked cells gives all False)."""
    return blocked_of(run.scene) | blocked_of(run.final_scene)


def _draw_targets(ax, scene, x0, y0, s, lw):
    from matplotlib.collections import LineCollection

    mask = np.asarray(scene.target_mask, bool)
    ax.add_collection(LineCollection(cell_edges(mask, x0, y0, s), colors=PALETTE["target"], linewidths=lw,
                                     zorder=4))
    if scene.target is not None:
        for ring in polygon_rings(scene.target):
            ax.plot(ring[:, 0], ring[:, 1], color="white", lw=1.0, ls="--", zorder=5)


def traffic_counts(run: FleetRun) -> np.ndarray:
    """``i64[H, W]``: how many times a rover drove into each cell over the run (a rover whose cell at
    step t differs from its cell at step t - 1 adds one to its cell at step t; waiting adds nothing,
    and the start cells count only when a rover drives back onto them). Cells outside the grid (none in
    a real run) are not counted."""
    _check_run(run)
    h, w = (int(v) for v in run.scene.shape)
    pos = np.asarray(run.pos, np.int64)
    moved = np.any(pos[1:] != pos[:-1], axis=-1)          # [T, N]
    cells = pos[1:][moved]                                   # [k, 2] (row, col) after each move
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)
    flat = cells[inside, 0] * w + cells[inside, 1]
    return np.bincount(flat, minlength=h * w).reshape(h, w).astype(np.int64)


def _map_axes(ax, scene, extent, blocked, s, x0, y0):
    """The parts every map panel shares: targets outlined, blocked cells, limits, aspect, axis labels
    in world units. Returns the legend handles of what was drawn (target, and blocked when any)."""
    from matplotlib.patches import Patch

    h, w = scene.shape
    _draw_targets(ax, scene, x0, y0, s, lw=1.2 if max(h, w) <= 80 else 0.6)
    handles = [Patch(facecolor=_TARGET_TINT, edgecolor=PALETTE["target"], label="target")]
    if draw_blocked(ax, blocked, s, (x0, y0)) is not None:
        handles.append(blocked_handle())
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x (world units)")
    ax.set_ylabel("y (world units, up)")
    return handles


def _legend_below(ax, handles, fontsize: int = 8):
    """The legend of a map panel in one row under its x label: over the map it would hide a corner,
    where rovers start."""
    return ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.11), ncol=len(handles),
                     fontsize=fontsize, frameon=False)


def _rover_handle(label: str, marker: str = "o"):
    from matplotlib.lines import Line2D

    return Line2D([], [], ls="", marker=marker, markersize=6, markerfacecolor=_rover_colors(3)[1],
                  markeredgecolor="black", markeredgewidth=0.6, label=label)


def _draw_rovers(ax, xy, colors, marker="o", zorder=6):
    """Every rover at ``xy`` (world, [N, 2]) in its colour, with its index up to ``_LABEL_MAX_ROVERS`` rovers."""
    n = len(xy)
    ax.scatter(xy[:, 0], xy[:, 1], c=colors, marker=marker, s=40 if n <= 16 else 14, edgecolors="black",
               linewidths=0.6, zorder=zorder)
    if n <= _LABEL_MAX_ROVERS:
        for i, (x, y) in enumerate(xy):
            ax.annotate(str(i), (x, y), xytext=(3, 3), textcoords="offset points", color="black", fontsize=7,
                        zorder=zorder + 1)


def _mass_panel(ax, run: FleetRun, summary: dict, t: int, n: int) -> None:
    """Delivered and outside mass over the steps; T50 and T90 drawn and labelled (or said not reached)."""
    steps = np.arange(t + 1)
    gain = np.asarray(run.delivered, np.float64) - float(run.delivered[0])
    initial = float(run.initial_outside)
    ax.plot(steps, gain, color=PALETTE["target"], lw=2, label="delivered since the start")
    ax.plot(steps, np.asarray(run.outside, np.float64), color="black", lw=2, label="outside the targets")
    for frac, key, ls in ((0.5, "T50", ":"), (0.9, "T90", "--")):
        level = frac * initial
        ax.axhline(level, color="grey", lw=0.8, ls=ls)
        at = summary[key]
        if at is None:    # said in the legend, where no curve runs
            ax.plot([], [], ls="none", label=f"{key} ({frac:.0%} delivered): not reached in {t} steps")
            continue
        ax.axvline(at, color=PALETTE["connector"], lw=1.2, ls=ls, label=f"{key} = {at} steps ({frac:.0%} delivered)")
        right = at > 0.8 * t          # near the end: the label left of its line, inside the axes
        ax.annotate(f"{key} = {at}", (at, level), xytext=(-4 if right else 4, 4), textcoords="offset points",
                    ha="right" if right else "left", fontsize=8, color=PALETTE["connector"], fontweight="bold",
                    gid=key)
    ax.set_xlabel("step")
    ax.set_ylabel("mass (objects)")
    ax.set_title(f"mass over time: {n} rover(s), {run.strategy}, {len(run.pushes)} pushes in {t} steps, "
                 f"stop: {run.stop_reason}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="center left")


def plot_fleet(run: FleetRun):
    """The run's figure (fleet.png), four panels (``FIGURE_PANELS``, each Axes' gid):

    - "mass": delivered mass and mass outside the targets over the steps, T50 and T90 marked and
      labelled (or said not reached);
    - "start": the initial counts (the piles), the targets, the blocked cells and every rover's start;
    - "traffic": how many times a rover drove into each cell (:func:`traffic_counts`);
    - "final": the final counts, the targets, the blocked cells and every rover's final cell.

    Counts on one colour scale in "start" and "final" (objects per cell; target cells tinted, not on
    the scale). Returns the matplotlib Figure.
    """
    import matplotlib.pyplot as plt

    t, n = _check_run(run)
    summary = summary_of(run)
    fig, axes = plt.subplots(2, 2, figsize=(13.5, 11.0))
    panels = dict(zip(FIGURE_PANELS, axes.ravel()))
    for name, ax in panels.items():
        ax.set_gid(name)
    _mass_panel(panels["mass"], run, summary, t, n)

    scene = run.scene
    x0, y0, s, extent, centre = _frame_of(scene)
    mask = np.asarray(scene.target_mask, bool)
    blocked = _blocked_cells(run)
    colors = _rover_colors(n)
    pos = np.asarray(run.pos)
    start_obj = np.where(mask, np.nan, np.asarray(scene.obj, np.float64))
    final_obj = np.where(mask, np.nan, np.asarray(run.final_scene.obj, np.float64))
    vmax = finite_max(start_obj, final_obj)

    def tint(ax):
        rgba = np.zeros(mask.shape + (4,))
        rgba[mask] = _TARGET_TINT
        ax.imshow(rgba, origin="lower", extent=extent, interpolation="nearest", zorder=1)

    for name, obj, cells, what in (("start", start_obj, pos[0], "start"), ("final", final_obj, pos[-1], "at the end")):
        ax = panels[name]
        im = ax.imshow(_finite(obj), origin="lower", extent=extent, cmap=MASS_CMAP, vmin=0, vmax=vmax,
                       interpolation="nearest", zorder=0)
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03).set_label("objects per cell")
        tint(ax)
        handles = _map_axes(ax, scene, extent, blocked, s, x0, y0)
        _draw_rovers(ax, centre(cells), colors, marker="^" if name == "start" else "o")
        _legend_below(ax, [_rover_handle(f"rover {what} (index)", "^" if name == "start" else "o"), *handles])
    panels["start"].set_title(f"start: piles ({float(run.initial_outside):.1f} objects outside the targets), "
                              f"{n} rover start(s)", fontsize=10)
    panels["final"].set_title(f"end: delivered {summary['delivered']:.1f} of {float(run.initial_outside):.1f}, "
                              f"remaining {summary['remaining']:.1f} objects", fontsize=10)

    ax = panels["traffic"]
    traffic = traffic_counts(run)
    im = ax.imshow(np.where(traffic > 0, traffic, np.nan), origin="lower", extent=extent, cmap=TRAFFIC_CMAP,
                   vmin=0, vmax=max(int(traffic.max()), 1), interpolation="nearest", zorder=0)
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03).set_label("rover moves into the cell (count)")
    tint(ax)
    _legend_below(ax, _map_axes(ax, scene, extent, blocked, s, x0, y0))
    ax.set_title(f"traffic: {int(traffic.sum())} rover moves over {t} steps, busiest cell {int(traffic.max())} "
                 "(white: never driven)", fontsize=10)
    fig.tight_layout()
    return fig


def frame_steps(n_frames: int, steps: int, max_frames: int) -> list[tuple[int, int]]:
    """Which frames to draw: ``(frame index, step index into pos)`` pairs, at most ``max_frames``.

    Frames are aligned to the end of ``pos`` (the last frame shows the last step), so a recording of
    T + 1 frames (the start included) and one of T (after each step) both map right. Subsampling is
    even and keeps the first and the last frame.
    """
    if n_frames <= 0:
        return []
    keep = np.unique(np.rint(np.linspace(0, n_frames - 1, min(n_frames, max(1, int(max_frames))))).astype(int))
    offset = steps + 1 - n_frames
    return [(int(i), int(min(max(i + offset, 0), steps))) for i in keep]


def animate_fleet(run: FleetRun, path, *, fps: int = 8, max_frames: int = DEFAULT_MAX_FRAMES, dpi: int = 90,
                  progress=None) -> int:
    """Write the recorded run step by step to ``path`` (``.gif`` with Pillow, ``.mp4`` with ffmpeg).

    Each frame: the mass, the counts per cell outside the targets (``MASS_CMAP``, one colour scale for
    the whole animation; empty cells pale), the target cells tinted and outlined, blocked cells as
    dark-grey squares, and every rover (one colour each, its index up to 16 rovers) with its current
    route as a line of its colour from the route's start; a legend below the map. At most
    ``max_frames`` frames (evenly subsampled, :func:`frame_steps`). progress: optional
    ``progress(i, n)`` after each rendered frame. Returns the frames written.
    Needs ``run.frames`` (``run_fleet(..., record=True)``).
    """
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    t, n = _check_run(run)
    frames = run.frames
    if not frames:
        raise ValueError("animate_fleet: the run has no frames; run it with record=True.")
    picks = frame_steps(len(frames), t, max_frames)
    scene = run.scene
    x0, y0, s, extent, centre = _frame_of(scene)
    h, w = scene.shape
    mask = np.asarray(scene.target_mask, bool)
    blocked = _blocked_cells(run)
    pos = np.asarray(run.pos)
    colors = _rover_colors(n)

    def mass(obj):   # counts outside the targets; target cells and non-finite counts left off the scale
        return _finite(np.where(mask, np.nan, np.asarray(obj, np.float64)))

    vmax = finite_max(*(mass(frames[i]["obj"]) for i, _ in picks))
    fig, ax = plt.subplots(figsize=(7.2, 7.0))
    fig.subplots_adjust(left=0.1, right=0.9, top=0.93, bottom=0.16)
    im = ax.imshow(mass(frames[picks[0][0]]["obj"]), origin="lower", extent=extent, cmap=MASS_CMAP, vmin=0,
                   vmax=vmax, interpolation="nearest", zorder=0)
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03).set_label("objects per cell (outside the targets)")
    tint = np.zeros((h, w, 4))
    tint[mask] = _TARGET_TINT
    ax.imshow(tint, origin="lower", extent=extent, interpolation="nearest", zorder=1)
    handles = _map_axes(ax, scene, extent, blocked, s, x0, y0)
    route_lines = [ax.plot([], [], color=colors[i], lw=1.8, alpha=0.9, zorder=6)[0] for i in range(n)]
    rovers = ax.scatter(np.zeros(n), np.zeros(n), c=colors, s=40 if n <= 16 else 14, edgecolors="black",
                        linewidths=0.6, zorder=7)
    labels = [ax.text(0, 0, str(i), color="black", fontsize=7, zorder=8) for i in range(n)] \
        if n <= _LABEL_MAX_ROVERS else []
    route_handle = Line2D([], [], color=colors[n // 2], lw=1.8, label="current route (rover's colour)")
    _legend_below(ax, [_rover_handle("rover (index)"), route_handle, *handles])
    title = ax.set_title("", fontsize=10)
    delivered = np.asarray(run.delivered, np.float64) - float(run.delivered[0])
    outside = np.asarray(run.outside, np.float64)
    shown = [0]   # frames reported to progress: FuncAnimation draws frame 0 once more to set up

    def draw(k):
        i, step = picks[k]
        f = frames[i]
        im.set_data(mass(f["obj"]))
        xy = centre(pos[step])
        rovers.set_offsets(xy)
        for line, route in zip(route_lines, f["routes"]):
            pts = centre(route) if route is not None and len(route) else np.zeros((0, 2))
            line.set_data(pts[:, 0], pts[:, 1])
        for label, (x, y) in zip(labels, xy):
            label.set_position((x + 0.3 * s, y + 0.3 * s))
        title.set_text(f"step {step}/{t}, {n} rover(s) ({run.strategy}): delivered {delivered[step]:.1f}, "
                       f"outside {outside[step]:.1f} objects")
        if progress is not None and k + 1 > shown[0]:
            shown[0] = k + 1
            progress(k + 1, len(picks))
        return im, rovers, title, *route_lines, *labels

    save_animation(fig, draw, len(picks), path, fps=fps, dpi=dpi)
    return len(picks)


# --------------------------------------------------------------------------------------------------
# Files


def write_fleet_outputs(run: FleetRun, run_folder, animate: bool, fps: int, *, extra_summary: dict | None = None,
                        max_frames: int = DEFAULT_MAX_FRAMES, progress=None) -> dict:
    """Write the run's files (module docstring) into ``run_folder`` (a :class:`jaxplan.core.outputs.RunFolder`
    already entered); returns ``{file name: path}`` of what was written.

    Cheapest first, each file atomically and recorded in the folder's manifest, so that a failing
    figure or animation leaves the numbers on disk. extra_summary: more keys for summary.json (the
    command's parameters); they cannot replace the run's own keys. fleet.gif only when ``animate``
    and the run has frames; max_frames and progress go to :func:`animate_fleet`.
    """
    import matplotlib.pyplot as plt

    summary = summary_of(run)
    clash = sorted(set(extra_summary or {}) & set(summary))
    if clash:
        raise ValueError(f"write_fleet_outputs: extra_summary repeats the run's own keys {clash}; rename them.")
    summary.update(extra_summary or {})
    arrays = trajectory_arrays(run)
    written = {
        "summary.json": run_folder.write_json("summary.json", summary),
        "trajectory.npz": run_folder.write("trajectory.npz", lambda fh: np.savez_compressed(fh, **arrays)),
        "pushes.json": run_folder.write_json("pushes.json", pushes_records(run)),
    }
    fig = plot_fleet(run)
    try:
        written["fleet.png"] = run_folder.write("fleet.png", lambda fh: fig.savefig(fh, format="png", dpi=110))
    finally:
        plt.close(fig)
    if animate and run.frames:
        with run_folder.staged("fleet.gif") as tmp:
            animate_fleet(run, tmp, fps=fps, max_frames=max_frames, progress=progress)
        written["fleet.gif"] = run_folder.file("fleet.gif")
    return {name: str(p) for name, p in written.items()}
