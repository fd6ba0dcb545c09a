"""What ``jaxplan rover`` writes: the per-route table, the Fig. 4-style top view and rendered frames."""
from __future__ import annotations

import numpy as np

__all__ = ["plot_check", "table_markdown", "render_frames"]


def table_markdown(rows: list[dict]) -> str:
    """Markdown table: predicted vs simulated delivered mass and tracking error per route."""
    head = ("| route | collected | predicted delivered | simulated delivered | spilled | left behind | "
            "lost | mean lat. err (cells) | max lat. err (cells) | time (s) | finite |")
    lines = [head, "|" + "---|" * 11]
    for i, r in enumerate(rows):
        lines.append(f"| {i} | {r['collected']:g} | {r['predicted_delivered']:.2f} | {r['delivered']:g} | "
                     f"{r['spilled']:g} | {r['left_behind']:g} | {r['lost']:g} | {r['mean_lateral']:.3f} | "
                     f"{r['max_lateral']:.3f} | {r['time']:.2f} | {r['finite']} |")
    return "\n".join(lines) + "\n"


def plot_check(scene, check, route: int = 0):
    """Top view of the 3D state before and after route ``route`` next to the 2D grids (Fig. 4 style).

    Left: the 2D grid before (counts) with the route; middle: particles and rover before and after
    (world x, y); right: the grid projected back from the physics. Every panel draws the scene's
    blocked cells as dark-grey squares (``jaxplan.transport.viz.draw_blocked``).
    """
    import matplotlib.pyplot as plt

    from jaxplan.transport.physics import bridge
    from jaxplan.transport.viz import blocked_handle, blocked_of, draw_blocked

    world, traj = check.world, check.trajectory
    s = world.cell_size
    ox, oy = world.origin
    h, w = scene.shape
    extent = (ox, ox + w * s, oy, oy + h * s)
    n_p = check.particle_cells[route].shape[0]
    before = world.particle_xyz(traj.qpos[route, 0])[:n_p]
    after = world.particle_xyz(traj.qpos[route, -1])[:n_p]
    obj_after, _ = bridge.projected_obj(scene, check, route)
    path = np.asarray(check.params.path[route])
    fig, axes = plt.subplots(1, 3, figsize=(15, 5))
    vmax = max(float(np.max(np.asarray(scene.obj))), float(obj_after.max()), 1.0)
    target = np.ma.masked_where(~np.asarray(scene.target_mask), np.ones(scene.shape))
    blocked = blocked_of(scene)
    for ax, grid, title in ((axes[0], np.asarray(scene.obj), "2D grid before (counts)"),
                            (axes[2], obj_after, "2D grid projected back after the push")):
        im = ax.imshow(grid, origin="lower", extent=extent, cmap="YlOrBr", vmin=0, vmax=vmax)
        ax.imshow(target, origin="lower", extent=extent, cmap="Blues", alpha=0.35, vmin=0, vmax=1.5)
        if draw_blocked(ax, blocked, s, (ox, oy), zorder=1.5) is not None:
            ax.legend(handles=[blocked_handle()], loc="upper left", fontsize=7)
        ax.plot(path[:, 0], path[:, 1], "-", color="#a855f7", lw=1.5)
        ax.set_title(title)
        fig.colorbar(im, ax=ax, fraction=0.046)
    ax = axes[1]
    ax.imshow(target, origin="lower", extent=extent, cmap="Blues", alpha=0.35, vmin=0, vmax=1.5)
    has_blocked = draw_blocked(ax, blocked, s, (ox, oy), zorder=0.5) is not None
    ax.scatter(before[:, 0], before[:, 1], s=8, c="#9ca3af", label="particles before")
    ax.scatter(after[:, 0], after[:, 1], s=8, c="#b45309", label="particles after")
    ax.plot(path[:, 0], path[:, 1], "-", color="#a855f7", lw=1.5, label="spline")
    q = traj.qpos[route]
    yaw = np.arctan2(2 * (q[:, 3] * q[:, 6] + q[:, 4] * q[:, 5]), 1 - 2 * (q[:, 5] ** 2 + q[:, 6] ** 2))
    blade = q[:, :2] + world.geometry.blade_front * np.stack([np.cos(yaw), np.sin(yaw)], -1)
    ax.plot(blade[:, 0], blade[:, 1], "--", color="#16a34a", lw=1.2, label="blade (simulated)")
    for k, style in ((0, "o"), (-1, "s")):
        ax.plot(q[k, 0], q[k, 1], style, color="black", ms=6)
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.set_title("3D state, top view (o start, s end)")
    handles, _ = ax.get_legend_handles_labels()
    ax.legend(handles=handles + ([blocked_handle()] if has_blocked else []), loc="upper left", fontsize=7)
    fig.tight_layout()
    return fig


def render_frames(check, route: int, n_frames: int = 8, width: int = 480, height: int = 360):
    """``u8[F, height, width, 3]`` offscreen renders of route ``route`` (needs a GL context; the CLI
    sets ``MUJOCO_GL=egl`` before importing mujoco). Raises on any rendering failure."""
    import mujoco

    world, traj = check.world, check.trajectory
    model = world.model
    data = mujoco.MjData(model)
    ticks = np.linspace(0, traj.qpos.shape[1] - 1, n_frames).astype(int)
    cam = mujoco.MjvCamera()
    h, w = world.shape
    cam.lookat[:] = [world.origin[0] + 0.5 * w * world.cell_size, world.origin[1] + 0.5 * h * world.cell_size, 0]
    cam.distance = 1.1 * max(h, w) * world.cell_size
    cam.elevation = -60
    cam.azimuth = 90
    frames = []
    with mujoco.Renderer(model, height=height, width=width) as renderer:
        for t in ticks:
            data.qpos[:] = traj.qpos[route, t]
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera=cam)
            frames.append(renderer.render().copy())
    return np.stack(frames)
