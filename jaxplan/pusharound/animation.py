"""Top-view animation of an executed pushing schedule (matplotlib; GIF with Pillow).

:func:`plot_state` draws one state: workspace, fixed obstacles (grey), movables (tan, each convex
piece a patch), the pushed movable highlighted, robots (dark disks), start and goal with their
``B(., W/2)`` disks and, when given, the W-clear corridor as a band of width W along the path (the
vehicle's swept disk: every point of the band is within W/2 of the path). :func:`animate_execution`
writes :class:`~jaxplan.pusharound.execution.Frames` as an animation (``.gif`` with Pillow, ``.mp4``
with ffmpeg, as :func:`jaxplan.transport.viz.animate_episode`), the corridor shown on the last frames;
:func:`save_final_png` writes the final state. Never selects a matplotlib backend.
"""
from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import LineString

__all__ = ["animate_execution", "corridor_band", "plot_state", "save_final_png"]

_FIXED = ("#9ca3af", "#374151")
_MOVABLE = ("#fcd9a8", "#b45309")
_ACTIVE = ("#fdba74", "#c2410c")
_ROBOT = "#111827"
_CORRIDOR = "#22c55e"


def corridor_band(path, width: float):
    """The corridor of a W-clear ``path f[P, 2]``: the path buffered by ``width / 2`` (a shapely
    Polygon), or None without a path."""
    if path is None or len(path) < 2:
        return None
    return LineString(np.asarray(path, np.float64)).buffer(0.5 * float(width), 32)


def _posed(pieces_xy, pose):
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    return [xy @ rot.T + np.asarray(pose[:2]) for xy in pieces_xy]


class _Drawing:
    """Patches of one axes, updated in place from frame to frame."""

    def __init__(self, ax, scene, title: str = ""):
        from matplotlib.patches import Circle  # noqa: PLC0415 (keep matplotlib optional at import time)
        from matplotlib.patches import Polygon as MplPolygon  # noqa: PLC0415

        self.ax, self.scene = ax, scene
        x0, y0, x1, y1 = scene.workspace
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="k", lw=1.5)
        for f in scene.fixed:
            for p in f.world_pieces():
                ax.add_patch(MplPolygon(np.asarray(p.exterior.coords), closed=True, fc=_FIXED[0], ec=_FIXED[1], lw=0.6))
        r = 0.5 * float(scene.width)
        for name, pt, col in (("S", scene.start, "#16a34a"), ("G", scene.goal, "#7c3aed")):
            ax.add_patch(Circle(pt, r, fc="none", ec=col, lw=1.2, ls="--", zorder=5))
            ax.text(pt[0], pt[1], name, ha="center", va="center", color=col, weight="bold", zorder=6)
        self.body_xy = [[np.asarray(p.exterior.coords)[:-1, :2] for p in m.pieces] for m in scene.movables]
        self.patches = [[ax.add_patch(MplPolygon(xy, closed=True, fc=_MOVABLE[0], ec=_MOVABLE[1], lw=0.7))
                         for xy in pieces] for pieces in self.body_xy]
        self.robots = [ax.add_patch(Circle(p, scene.robot_radius, fc=_ROBOT, ec="white", lw=0.5, zorder=4))
                       for p in np.asarray(scene.robots).reshape(-1, 2)]
        self.band = ax.add_patch(MplPolygon(np.zeros((3, 2)), closed=True, fc=_CORRIDOR, ec=_CORRIDOR, alpha=0.25,
                                            lw=0.8, visible=False, zorder=2))
        (self.line,) = ax.plot([], [], color="#15803d", lw=1.6, zorder=3)
        ax.set_xlim(x0 - 0.1, x1 + 0.1)
        ax.set_ylim(y0 - 0.1, y1 + 0.1)
        ax.set_aspect("equal")
        self.title = ax.set_title(title, fontsize=9)

    def update(self, poses, robots, active: int = -1, path=None, title=None):
        for mi, (pieces, patches) in enumerate(zip(self.body_xy, self.patches)):
            col = _ACTIVE if mi == active else _MOVABLE
            for xy, patch in zip(_posed(pieces, poses[mi]), patches):
                patch.set_xy(xy)
                patch.set_facecolor(col[0])
                patch.set_edgecolor(col[1])
        for c, p in zip(self.robots, np.asarray(robots).reshape(-1, 2)):
            c.center = (float(p[0]), float(p[1]))
        band = corridor_band(path, self.scene.width)
        if band is not None:
            # A band clipped by nothing: draw its exterior (a buffered polyline has no holes unless the
            # path loops, which a W-clear walk does not).
            poly = band if band.geom_type == "Polygon" else max(band.geoms, key=lambda g: g.area)
            self.band.set_xy(np.asarray(shapely.get_exterior_ring(poly).coords))
            self.band.set_visible(True)
            self.line.set_data(*np.asarray(path).T)
        else:
            self.band.set_visible(False)
            self.line.set_data([], [])
        if title is not None:
            self.title.set_text(title)
        return [p for ps in self.patches for p in ps] + self.robots + [self.band, self.line, self.title]


def plot_state(scene, poses=None, robots=None, path=None, ax=None, active: int = -1, title: str | None = None):
    """Draw ``scene`` with movables at ``poses f[M, 3]`` and robots at ``robots f[N, 2]`` (default: the
    scene's) and the corridor of ``path f[P, 2]`` (band of width W); returns the axes."""
    import matplotlib.pyplot as plt  # noqa: PLC0415

    if ax is None:
        _, ax = plt.subplots(figsize=(8, 5.5))
    drawing = _Drawing(ax, scene)
    drawing.update(scene.poses if poses is None else np.asarray(poses), scene.robots if robots is None else robots,
                   active, path, title if title is not None else f"W = {scene.width:g} m")
    return ax


def _frame_title(execution, i: int) -> str:
    fr = execution.frames
    k = int(fr.push[i])
    what = "start" if k < 0 else f"push {k + 1}/{len(execution.executed)} ({fr.phase[i]})"
    return f"t = {fr.time[i]:5.1f} s   {what}"


def animate_execution(scene, execution, path, *, fps: int = 10, dpi: int = 80, max_frames: int = 150,
                      hold_s: float = 1.5, progress=None) -> None:
    """Write ``execution`` (an :class:`~jaxplan.pusharound.execution.Execution`, or any object with
    ``frames``, ``executed`` and ``w_clear_path``) as an animation at ``path`` (.gif or .mp4).

    At most ``max_frames`` recorded frames are drawn (evenly subsampled, the last always kept); the
    final state with the W-clear corridor is held for ``hold_s`` seconds. progress: optional
    ``progress(i, n)`` after each rendered frame.
    """
    import matplotlib.pyplot as plt  # noqa: PLC0415

    from jaxplan.core import save_animation  # noqa: PLC0415

    fr = execution.frames
    n_rec = len(fr.time)
    if n_rec == 0:
        raise ValueError("animate_execution: the execution has no frames (record_every too large?).")
    if fps < 1 or max_frames < 2:
        raise ValueError(f"fps, max_frames: must be >= 1 and >= 2; got {fps!r}, {max_frames!r}.")
    pick = np.unique(np.r_[np.linspace(0, n_rec - 1, min(n_rec, max_frames)).round().astype(int), n_rec - 1])
    hold = max(1, int(round(hold_s * fps)))
    order = list(pick) + [n_rec - 1] * hold
    n = len(order)
    fig, ax = plt.subplots(figsize=(7.5, 7.5 * (scene.workspace[3] - scene.workspace[1])
                                    / (scene.workspace[2] - scene.workspace[0]) + 0.6))
    drawing = _Drawing(ax, scene)
    fig.tight_layout()
    executed = execution.executed

    def draw(j):
        i = order[j]
        k = int(fr.push[i])
        active = int(np.asarray(executed[k].task.movable)) if 0 <= k < len(executed) else -1
        last = j >= len(pick) - 1
        title = _frame_title(execution, i)
        if last:
            title = (f"final, t = {fr.time[i]:.1f} s: " + ("W-clear corridor" if execution.w_clear_path is not None
                                                           else "no W-clear path"))
        out = drawing.update(fr.poses[i], fr.robots[i], active, execution.w_clear_path if last else None, title)
        if progress is not None:
            progress(j + 1, n)
        return out

    save_animation(fig, draw, n, path, fps=fps, dpi=dpi)


def save_final_png(scene, poses, robots, path, out, *, dpi: int = 110, title: str | None = None) -> None:
    """Write the state (``poses f[M, 3]``, ``robots f[N, 2]``) with the corridor of ``path`` as a PNG at
    ``out`` (a path or a binary file object)."""
    import matplotlib.pyplot as plt  # noqa: PLC0415

    ax = plot_state(scene, poses, robots, path, title=title)
    try:
        ax.figure.savefig(out, format="png", dpi=dpi, bbox_inches="tight")
    finally:
        plt.close(ax.figure)
