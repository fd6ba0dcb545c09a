"""Plots of the trajectory fabric, in the style of the paper's Fig. 2d.

:func:`plot_fabric` draws, in world coordinates (x to the right, y up; grid rows are y, so row 0 is at
the bottom, as with ``imshow(..., origin="lower")``):

- the look-back heatmap ``H(X)`` (Eq. 10) as the background (``hot`` colormap, hotter = stronger
  incoming flow), with a colorbar;
- target cells tinted and outlined, and the target polygon (``scene.target``) when the scene has one;
- the aggregate counts: numbers in the cells on small grids, faint dots (area ~ count) otherwise;
- green arrows: the first-hop heading ``v(C)`` of every occupied cell (the selected target path);
- orange arrows: the connector heading of every root that has a connector (Section 3.4);
- highway cells (Eq. 11) outlined in cyan;
- blocked cells (``scene.blocked``: buildings, equipment, no-go zones) as solid dark-grey squares;
- optionally, selected paths ``P*(C)`` read from the continuation table, as polylines.

Every figure of a scene that jaxplan draws (fabric, episode, fleet, rover check) shows blocked cells
the same way, with :func:`draw_blocked`, and labels them "blocked" (:func:`blocked_handle`) in the
legend of the panel that draws them.

This module never selects a matplotlib backend; scripts without a display should call
``matplotlib.use("Agg")`` before importing pyplot (the ``jaxplan`` CLI does).
"""
from __future__ import annotations

import numpy as np

from jaxplan.core import save_animation

__all__ = ["BLOCKED_LABEL", "PALETTE", "animate_episode", "blocked_handle", "blocked_of", "cell_edges", "draw_blocked",
           "plot_episode", "plot_fabric", "polygon_rings"]

# Above this many cells per side, counts are drawn as dots instead of numbers.
_TEXT_MAX_SIDE = 30
# At most about this many arrows per side; larger grids are subsampled with a stride.
_ARROWS_MAX_SIDE = 72

_GREEN = "#22c55e"
_ORANGE = "#f97316"
_HIGHWAY = "#22d3ee"
_TARGET = "#3b82f6"
_PATH_COLORS = ("#a855f7", "#ec4899", "#14b8a6", "#eab308", "#6366f1", "#84cc16")
# Blocked cells: a solid dark-grey fill, their region outlined in a lighter grey (it stays visible on
# the black end of the ``hot`` heatmap).
_BLOCKED = "#404040"
_BLOCKED_EDGE = "#a3a3a3"
# The colours above by role, for other systems' plots that draw the same things the same way.
PALETTE = {"heading": _GREEN, "connector": _ORANGE, "highway": _HIGHWAY, "target": _TARGET, "paths": _PATH_COLORS,
           "blocked": _BLOCKED, "blocked_edge": _BLOCKED_EDGE}
# The legend label (and the artists' label and gid) of the blocked-cell layer.
BLOCKED_LABEL = "blocked"


def cell_edges(mask: np.ndarray, x0: float, y0: float, s: float) -> np.ndarray:
    """Segments ``f[N, 2, 2]`` (world units) of the outline of the cells where ``mask`` is True."""
    h, w = mask.shape
    padded = np.pad(mask, 1, constant_values=False)
    segs = []
    # vertical edges: between column c-1 and c, for c in 0..W
    diff_v = padded[1:-1, :-1] != padded[1:-1, 1:]          # [H, W+1]
    r, c = np.nonzero(diff_v)
    x = x0 + c * s
    segs.append(np.stack([np.stack([x, y0 + r * s], -1), np.stack([x, y0 + (r + 1) * s], -1)], 1))
    # horizontal edges: between row r-1 and r, for r in 0..H
    diff_h = padded[:-1, 1:-1] != padded[1:, 1:-1]          # [H+1, W]
    r, c = np.nonzero(diff_h)
    y = y0 + r * s
    segs.append(np.stack([np.stack([x0 + c * s, y], -1), np.stack([x0 + (c + 1) * s, y], -1)], 1))
    out = np.concatenate(segs, 0)
    return out.reshape(-1, 2, 2).astype(np.float64)


def blocked_of(scene) -> np.ndarray:
    """``bool[H, W]`` numpy: ``scene.blocked``, or all False for a scene without blocked cells."""
    blocked = getattr(scene, "blocked", None)
    if blocked is None:
        return np.zeros(tuple(scene.shape), bool)
    return np.asarray(blocked, bool)


def draw_blocked(ax, blocked, cell_size, origin, *, zorder: float = 2.5):
    """Draw the blocked cells as solid dark-grey squares (their region outlined in lighter grey).

    ax: matplotlib Axes in world coordinates (rows = y, ``origin="lower"``). blocked: ``bool[H, W]``
    (None or all False draws nothing). cell_size: world units per cell; origin: world (x, y) of the
    grid corner, so cell (r, c) covers ``[x0 + c s, x0 + (c + 1) s] x [y0 + r s, y0 + (r + 1) s]``.
    zorder: of the fill (the outline sits just above it); the default covers heatmaps and tints.

    Returns the fill, an ``AxesImage`` with label and gid ``BLOCKED_LABEL`` ("blocked"), or None
    when nothing is blocked. The axes limits are left as they are. Legends: :func:`blocked_handle`.
    """
    from matplotlib.collections import LineCollection
    from matplotlib.colors import to_rgba
    from matplotlib.image import AxesImage

    if blocked is None:
        return None
    mask = np.asarray(blocked, bool)
    if mask.ndim != 2:
        raise ValueError(f"draw_blocked: blocked must be a bool [H, W] mask; got shape {mask.shape}.")
    if not mask.any():
        return None
    s = float(np.asarray(cell_size))
    x0, y0 = (float(v) for v in np.asarray(origin, np.float64).reshape(2))
    h, w = mask.shape
    rgba = np.zeros((h, w, 4))
    rgba[mask] = to_rgba(_BLOCKED, 1.0)
    # added directly (not through imshow): neither the limits nor the aspect of ``ax`` change
    image = AxesImage(ax, interpolation="nearest", origin="lower", extent=(x0, x0 + w * s, y0, y0 + h * s),
                      zorder=zorder, label=BLOCKED_LABEL, gid=BLOCKED_LABEL)
    image.set_data(rgba)
    ax.add_image(image)
    outline = LineCollection(cell_edges(mask, x0, y0, s), colors=_BLOCKED_EDGE,
                             linewidths=0.8 if max(h, w) <= 80 else 0.4, zorder=zorder + 0.01)
    outline.set_gid(BLOCKED_LABEL)
    ax.add_collection(outline, autolim=False)
    return image


def blocked_handle(label: str = BLOCKED_LABEL):
    """A legend handle (``matplotlib.patches.Patch``) for the blocked cells drawn by :func:`draw_blocked`."""
    from matplotlib.patches import Patch

    return Patch(facecolor=_BLOCKED, edgecolor=_BLOCKED_EDGE, label=label)


def polygon_rings(target):
    """Every ring (exterior and interiors) of a Polygon / MultiPolygon as ``f[N, 2]`` arrays."""
    polys = list(getattr(target, "geoms", [target]))
    rings = []
    for poly in polys:
        rings.append(np.asarray(poly.exterior.coords)[:, :2])
        rings.extend(np.asarray(ring.coords)[:, :2] for ring in poly.interiors)
    return rings


def finite_max(*arrays) -> float:
    """The largest finite value of ``arrays`` if it is > 0, else 1.0: a colour scale's top that NaN
    or inf (e.g. ``scene.dist`` on blocked and cut-off cells) can neither break nor stretch."""
    top = 0.0
    for a in arrays:
        a = np.asarray(a, np.float64)
        finite = a[np.isfinite(a)]
        if finite.size:
            top = max(top, float(finite.max()))
    return top if top > 0 else 1.0


def _stride(h: int, w: int) -> int:
    return max(1, -(-max(h, w) // _ARROWS_MAX_SIDE))


def _arrow_mask(mask: np.ndarray, stride: int) -> np.ndarray:
    if stride == 1:
        return mask
    keep = np.zeros_like(mask)
    keep[::stride, ::stride] = True
    return mask & keep


def plot_fabric(scene, fabric, connectors=None, ax=None, path_sources=None):
    """Draw the fabric of ``scene`` like the paper's Fig. 2d and return the matplotlib Figure.

    scene: the :class:`jaxplan.Scene` the fabric was built for (its ``target`` polygon is drawn
      when not None). fabric: :class:`jaxplan.Fabric` from ``build_fabric(scene, params)``.
    connectors: optional :class:`jaxplan.Connectors` from ``plan_connectors``; adds orange arrows at
      the roots that have a connector.
    ax: optional matplotlib Axes to draw into (its figure is returned); a new figure otherwise.
    path_sources: optional ``[B, 2]`` (row, col) cells; their selected paths ``P*(C)`` are drawn as
      polylines (a boundary fallback ends at the closest target-boundary point).

    Coordinates are world units: cell (r, c) is centred at
    ``origin + ((c + 0.5) s, (r + 0.5) s)``, rows are y and y increases upward.
    """
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    heat = np.asarray(fabric.heat, dtype=np.float64)
    h, w = heat.shape
    if tuple(scene.shape) != (h, w):
        raise ValueError(f"plot_fabric: the fabric is {h}x{w} but the scene is "
                         f"{scene.shape[0]}x{scene.shape[1]}; pass the scene the fabric was built for.")
    s = float(np.asarray(scene.cell_size))
    x0, y0 = (float(v) for v in np.asarray(scene.origin))
    extent = (x0, x0 + w * s, y0, y0 + h * s)
    obj = np.asarray(scene.obj, dtype=np.float64)
    target_mask = np.asarray(scene.target_mask, dtype=bool)
    occupied = np.asarray(fabric.occupied, dtype=bool)
    highways = np.asarray(fabric.highways, dtype=bool)
    heading = np.asarray(fabric.heading, dtype=np.float64)
    xs = x0 + (np.arange(w) + 0.5) * s
    ys = y0 + (np.arange(h) + 0.5) * s
    cx, cy = np.meshgrid(xs, ys)

    if ax is None:
        side = 7.5 if max(h, w) <= 40 else 9.0
        fig, ax = plt.subplots(figsize=(side * min(1.6, max(0.6, w / h)) + 1.5, side))
    else:
        fig = ax.figure

    blocked = blocked_of(scene)

    # Heatmap background (non-finite values left blank; they never set the colour scale).
    heat = np.where(np.isfinite(heat), heat, np.nan)
    vmax = finite_max(heat)
    im = ax.imshow(heat, origin="lower", extent=extent, cmap="hot", vmin=0.0, vmax=vmax,
                   interpolation="nearest", zorder=0)
    cbar = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
    cbar.set_label("heat H(X) (objects; hotter = stronger incoming flow)")

    # Target cells: tint and outline; then the target polygon itself.
    tint = np.zeros((h, w, 4))
    tint[target_mask] = (0.23, 0.51, 0.96, 0.45)
    ax.imshow(tint, origin="lower", extent=extent, interpolation="nearest", zorder=1)
    edge_lw = 1.2 if max(h, w) <= 80 else 0.6
    ax.add_collection(LineCollection(cell_edges(target_mask, x0, y0, s), colors=_TARGET,
                                     linewidths=edge_lw, zorder=2))
    # Blocked cells: over the heatmap, under the outlines, counts and arrows.
    draw_blocked(ax, blocked, s, (x0, y0), zorder=1.5)
    if scene.target is not None:
        for ring in polygon_rings(scene.target):
            ax.plot(ring[:, 0], ring[:, 1], color="white", lw=1.3, ls="--", zorder=6)

    # Object counts.
    has_obj = obj > 0
    if max(h, w) <= _TEXT_MAX_SIDE:
        fontsize = max(4.0, min(8.0, 200.0 / max(h, w)))
        for r, c in zip(*np.nonzero(has_obj)):
            val = obj[r, c]
            label = f"{val:.0f}" if float(val).is_integer() else f"{val:.1f}"
            ax.text(cx[r, c] - 0.3 * s, cy[r, c] - 0.3 * s, label, ha="center", va="center",
                    fontsize=fontsize, color="white", alpha=0.55, zorder=3)
    elif has_obj.any():
        sizes = 12.0 * obj[has_obj] / obj[has_obj].max() * (40.0 / max(h, w, 40))
        ax.scatter(cx[has_obj], cy[has_obj], s=sizes, c="white", alpha=0.25, linewidths=0,
                   zorder=3)

    # Highway cells.
    if highways.any():
        ax.add_collection(LineCollection(cell_edges(highways, x0, y0, s), colors=_HIGHWAY,
                                         linewidths=edge_lw, zorder=4))

    # Arrows: green first-hop headings, orange connector headings.
    stride = _stride(h, w)
    arrow_len = 0.6 * s * stride
    width = 0.0035 if max(h, w) <= 40 else 0.0022
    quiver_kw = dict(angles="xy", scale_units="xy", scale=1.0, pivot="tail")
    # Arrows start at the cell centre. Connector arrows are drawn wider and below the green ones,
    # so both stay visible where they point the same way.
    green = _arrow_mask(occupied & np.any(heading != 0, axis=-1), stride)
    if green.any():
        ax.quiver(cx[green], cy[green], heading[green][:, 0] * arrow_len,
                  heading[green][:, 1] * arrow_len, color=_GREEN, width=width, zorder=6,
                  **quiver_kw)
    n_conn = 0
    if connectors is not None:
        has_conn = np.asarray(connectors.has_connector, dtype=bool)
        n_conn = int(has_conn.sum())
        c_head = np.asarray(connectors.heading, dtype=np.float64)
        orange = _arrow_mask(has_conn & np.any(c_head != 0, axis=-1), stride)
        if orange.any():
            ax.quiver(cx[orange], cy[orange], c_head[orange][:, 0] * arrow_len,
                      c_head[orange][:, 1] * arrow_len, color=_ORANGE, width=2.2 * width,
                      zorder=5, **quiver_kw)

    # Selected paths.
    n_paths = 0
    if path_sources is not None:
        n_paths = _draw_paths(ax, scene, fabric, path_sources, x0, y0, s)

    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x (world units; column c at x0 + (c + 0.5) s)")
    ax.set_ylabel("y (world units, up; row r at y0 + (r + 0.5) s)")
    name = f" '{scene.name}'" if getattr(scene, "name", None) else ""
    ax.set_title(f"Trajectory fabric{name}, {h}x{w} (cf. Fig. 2d)\n"
                 "heat H(X), first-hop headings, highways; rows = y, y up (origin lower)",
                 fontsize=10)

    handles = [
        Line2D([], [], color=_GREEN, marker=r"$\rightarrow$", ls="", markersize=12,
               label="first-hop heading v(C)"),
        Patch(facecolor="none", edgecolor=_HIGHWAY, label=f"highway cells ({int(highways.sum())})"),
        Patch(facecolor=(0.23, 0.51, 0.96, 0.45), edgecolor=_TARGET, label="target cells"),
    ]
    if blocked.any():
        handles.append(blocked_handle())
    if connectors is not None:
        handles.insert(1, Line2D([], [], color=_ORANGE, marker=r"$\rightarrow$", ls="",
                                 markersize=12, label=f"connector heading ({n_conn} roots)"))
    if scene.target is not None:
        handles.append(Line2D([], [], color="white", ls="--", label="target polygon"))
    if n_paths:
        handles.append(Line2D([], [], color=_PATH_COLORS[0], lw=2, label="selected paths P*(C)"))
    leg = ax.legend(handles=handles, loc="upper left", fontsize=7, framealpha=0.75,
                    facecolor="#333333", labelcolor="white")
    leg.set_zorder(10)
    return fig


def _draw_paths(ax, scene, fabric, path_sources, x0, y0, s) -> int:
    """Draw ``P*(C)`` for every (row, col) in ``path_sources``; returns how many were drawn."""
    from jaxplan.transport.fabric import extract_paths

    src = np.asarray(path_sources)
    if src.size == 0:
        return 0
    if not np.issubdtype(src.dtype, np.integer) and not np.all(np.equal(np.mod(src, 1), 0)):
        raise ValueError(f"plot_fabric: path_sources must be integer (row, col) cells; got {src!r}.")
    src = src.astype(np.int64).reshape(-1, 2)
    h, w = scene.shape
    bad = (src[:, 0] < 0) | (src[:, 0] >= h) | (src[:, 1] < 0) | (src[:, 1] >= w)
    if bad.any():
        raise ValueError(f"plot_fabric: path_sources row {int(np.argmax(bad))} = "
                         f"{tuple(src[bad][0])} lies outside the {h}x{w} grid.")
    occupied = np.asarray(fabric.occupied, dtype=bool)
    paths = extract_paths(fabric, src, detour=scene.detour)
    cells = np.asarray(paths.cells)
    n_cells = np.asarray(paths.n_cells)
    target_mask = np.asarray(scene.target_mask, dtype=bool)
    dist = np.asarray(scene.dist, dtype=np.float64)
    tvec = np.asarray(scene.tvec, dtype=np.float64)
    detour = getattr(scene, "detour", None)
    no_detour = np.ones((h, w), bool) if detour is None else np.asarray(detour) < 0
    drawn = 0
    for i, (r0, c0) in enumerate(src):
        if not occupied[r0, c0]:
            continue  # no path from an empty or target cell
        rc = cells[i, : int(n_cells[i])]
        pts = np.stack([x0 + (rc[:, 1] + 0.5) * s, y0 + (rc[:, 0] + 0.5) * s], -1)
        lr, lc = rc[-1]
        if not target_mask[lr, lc] and no_detour[lr, lc] and np.isfinite(dist[lr, lc]):
            # A path that does not end by entering a target cell ends with a boundary fallback:
            # the straight segment to the closest boundary point, after the detour steps around
            # blocked cells (listed as path cells); none from a cell cut off by blocked cells,
            # whose ``dist`` is inf.
            pts = np.concatenate([pts, pts[-1:] + dist[lr, lc] * tvec[lr, lc][None]], 0)
        color = _PATH_COLORS[drawn % len(_PATH_COLORS)]
        ax.plot(pts[:, 0], pts[:, 1], color=color, lw=2.0, alpha=0.9, zorder=7,
                solid_capstyle="round")
        ax.plot(pts[0, 0], pts[0, 1], marker="o", color=color, markersize=5, zorder=8)
        drawn += 1
    return drawn


# --------------------------------------------------------------------------------------------------
# Episodes


def plot_episode(scene, episode):
    """The final figure of an episode: mass over pushes (left) and the final counts (right).

    scene: the scene the episode started from; episode: :class:`jaxplan.transport.episode.Episode`.
    """
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(12.5, 5.2))
    pushes = np.concatenate([[0], episode.pushes])
    start = lambda a, first: np.concatenate([[first], np.asarray(a, float)])  # noqa: E731
    left.plot(pushes, start(episode.delivered, 0.0), color=_TARGET, lw=2, label="delivered (cumulative)")
    left.plot(pushes, start(episode.remaining, episode.initial_remaining), color="black", lw=2,
              label="remaining outside the target")
    left.plot(pushes, start(episode.spilled, 0.0), color=_ORANGE, lw=1.5, ls="--",
              label="spilled (cumulative; spilled mass is pushed again)")
    rearr = np.nonzero(np.asarray(episode.mode) == 1)[0]
    if len(rearr):
        left.scatter(episode.pushes[rearr], np.asarray(episode.remaining)[rearr], marker="^", color=_HIGHWAY,
                     edgecolor="black", zorder=5, label="Rearrange pushes (via highway)")
    left.set_xlabel("push")
    left.set_ylabel("mass (objects)")
    left.set_title(f"{episode.n_pushes} pushes, stop: {episode.stop_reason}", fontsize=10)
    left.grid(alpha=0.3)
    left.legend(fontsize=8)

    h, w = scene.shape
    s = float(np.asarray(scene.cell_size))
    x0, y0 = (float(v) for v in np.asarray(scene.origin))
    extent = (x0, x0 + w * s, y0, y0 + h * s)
    final = np.asarray(episode.final_obj, float)
    target_mask = np.asarray(scene.target_mask, bool)
    im = right.imshow(np.where(target_mask, np.nan, final), origin="lower", extent=extent, cmap="viridis",
                      interpolation="nearest")
    fig.colorbar(im, ax=right, fraction=0.046, pad=0.03).set_label("objects left per cell")
    from matplotlib.collections import LineCollection

    right.add_collection(LineCollection(cell_edges(target_mask, x0, y0, s), colors=_TARGET, linewidths=1.2))
    blocked = blocked_of(scene)
    if draw_blocked(right, blocked, s, (x0, y0)) is not None:
        right.legend(handles=[blocked_handle()], loc="upper left", fontsize=7, framealpha=0.75)
    totals = episode.totals()
    right.set_title(f"final counts: delivered {totals['delivered']:.1f} of {episode.initial_remaining:.1f}, "
                    f"remaining {totals['remaining']:.1f}", fontsize=10)
    right.set_aspect("equal")
    right.set_xlabel("x (world units)")
    right.set_ylabel("y (world units, up)")
    fig.tight_layout()
    return fig


def animate_episode(scene, episode, path, *, fps: int = 4, dpi: int = 90, progress=None):
    """Write the episode tick by tick as an animation (``.gif`` with Pillow, ``.mp4`` with ffmpeg).

    Each frame shows the heatmap and first-hop headings *before* the push, highways, the connector
    of a Rearrange push (orange) and the pushed route's spline (white). Needs ``run_episode(...,
    record=True)``. progress: optional callable ``progress(i, n)`` after each rendered frame.
    """
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    frames = episode.frames
    if not frames:
        raise ValueError("animate_episode: the episode has no frames; run it with record=True "
                         "(and at least one push).")
    h, w = scene.shape
    s = float(np.asarray(scene.cell_size))
    x0, y0 = (float(v) for v in np.asarray(scene.origin))
    extent = (x0, x0 + w * s, y0, y0 + h * s)
    xs = x0 + (np.arange(w) + 0.5) * s
    ys = y0 + (np.arange(h) + 0.5) * s
    cx, cy = np.meshgrid(xs, ys)
    target_mask = np.asarray(scene.target_mask, bool)
    vmax = finite_max(*(f["heat"] for f in frames))
    stride = _stride(h, w)
    centre = lambda cells: np.stack([x0 + (cells[:, 1] + 0.5) * s, y0 + (cells[:, 0] + 0.5) * s], -1)  # noqa: E731

    fig, ax = plt.subplots(figsize=(7.2, 6.4))
    im = ax.imshow(np.where(np.isfinite(frames[0]["heat"]), frames[0]["heat"], np.nan), origin="lower",
                   extent=extent, cmap="hot", vmin=0, vmax=vmax, interpolation="nearest")
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03).set_label("heat H(X) before the push (objects)")
    ax.add_collection(LineCollection(cell_edges(target_mask, x0, y0, s), colors=_TARGET, linewidths=1.2))
    highway_lines = LineCollection([], colors=_HIGHWAY, linewidths=0.9)
    ax.add_collection(highway_lines)
    draw_blocked(ax, blocked_of(scene), s, (x0, y0))   # static: the same cells in every frame
    quiver = ax.quiver(cx[::stride, ::stride], cy[::stride, ::stride], np.zeros_like(cx[::stride, ::stride]),
                       np.zeros_like(cy[::stride, ::stride]), color=_GREEN, angles="xy", scale_units="xy",
                       scale=1.0, width=0.004)
    (spline_line,) = ax.plot([], [], color="white", lw=2.2)
    (conn_line,) = ax.plot([], [], color=_ORANGE, lw=3.0, alpha=0.9)
    (start_dot,) = ax.plot([], [], "o", color="white", markeredgecolor="black")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    title = ax.set_title("")
    n = len(frames)

    def draw(i):
        f = frames[i]
        im.set_data(np.where(np.isfinite(f["heat"]), f["heat"], np.nan))
        highway_lines.set_segments(list(cell_edges(f["highways"], x0, y0, s)))
        # NaN hides the arrow: only occupied cells carry a heading
        head = np.where(f["occupied"][..., None], f["heading"], np.nan)[::stride, ::stride] * 0.6 * s * stride
        quiver.set_UVC(head[..., 0], head[..., 1])
        spline = f["spline"]
        spline_line.set_data(spline[:, 0], spline[:, 1]) if len(spline) else spline_line.set_data([], [])
        conn = centre(f["connector"]) if len(f["connector"]) else np.zeros((0, 2))
        conn_line.set_data(conn[:, 0], conn[:, 1])
        first = centre(f["route"][:1])
        start_dot.set_data(first[:, 0], first[:, 1])
        mode = "Rearrange (connector + highway)" if f["mode"] else "Deliver"
        title.set_text(f"push {i + 1}/{n}: {mode}; delivered {episode.delivered[i]:.1f}, "
                       f"remaining {episode.remaining[i]:.1f}")
        if progress is not None:
            progress(i + 1, n)
        return im, highway_lines, quiver, spline_line, conn_line, start_dot, title

    save_animation(fig, draw, n, path, fps=fps, dpi=dpi)
