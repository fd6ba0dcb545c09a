"""Issue 45: every figure of a transport scene draws its blocked cells, as solid dark-grey squares
(``viz.draw_blocked``), labelled "blocked" where the panel has a legend; ``dist`` = inf on blocked and
cut-off cells neither breaks a plot nor stretches its colour scale.

One 12 x 12 scene with a 3 x 3 block (rows and columns 4-6), material off the block, the target in
the top-right corner. "Drawn" is checked twice: the Axes holds the blocked layer, and the rendered
pixels at a blocked cell's centre are the dark grey while a free cell's are not."""
from __future__ import annotations

import io

import matplotlib
import numpy as np
import pytest

from jaxplan.transport import viz
from jaxplan.transport.scene import Scene, box

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

BLOCK = (slice(4, 7), slice(4, 7))
BLOCKED_CELL = (5, 5)   # the middle of the block
FREE_CELL = (10, 1)     # empty, far from the block and the target
GREY = np.array([0x40, 0x40, 0x40])


def _blocked_mask():
    mask = np.zeros((12, 12), bool)
    mask[BLOCK] = True
    return mask


def _scene(blocked=True):
    obj = np.zeros((12, 12))
    obj[1:3, 1:10] = 2.0      # below the block
    obj[8:10, 1:4] = 1.0      # left of the target, above the block
    return Scene.from_arrays(obj, box(9.0, 9.0, 12.0, 12.0), blocked=_blocked_mask() if blocked else None,
                             name="blocked" if blocked else "open")


@pytest.fixture(scope="module")
def planned():
    from jaxplan.transport import EpisodeParams, FabricParams, build_fabric, plan_connectors, run_episode

    scene = _scene()
    params = FabricParams()
    fabric = build_fabric(scene, params)
    connectors = plan_connectors(scene, params, fabric)
    episode = run_episode(scene, params, episode=EpisodeParams(max_pushes=4), record=True)
    return scene, fabric, connectors, episode


def _pixel(rgb: np.ndarray, ax, cell, scale: float = 1.0) -> np.ndarray:
    """RGB at the centre of ``cell`` (row, col; world = cell index + 0.5 with unit cells at the origin)
    in an image rendered from ``ax``'s figure at ``scale`` times its dpi."""
    x, y = ax.transData.transform((cell[1] + 0.5, cell[0] + 0.5)) * scale
    return rgb[int(round(rgb.shape[0] - y)), int(round(x)), :3].astype(int)


def _render(fig) -> np.ndarray:
    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    buf.seek(0)
    return np.asarray(Image.open(buf).convert("RGB"))


def _assert_drawn(fig, ax):
    """The blocked layer is on ``ax`` and the PNG shows dark grey at a blocked cell, not at a free one."""
    layers = [im for im in ax.get_images() if im.get_gid() == viz.BLOCKED_LABEL]
    assert len(layers) == 1
    alpha = np.asarray(layers[0].get_array())[..., 3]
    np.testing.assert_array_equal(alpha > 0, _blocked_mask())
    rgb = _render(fig)
    assert np.abs(_pixel(rgb, ax, BLOCKED_CELL) - GREY).max() <= 3
    assert np.abs(_pixel(rgb, ax, FREE_CELL) - GREY).max() > 20


def _legend_labels(ax):
    legend = ax.get_legend()
    return [] if legend is None else [t.get_text() for t in legend.get_texts()]


# --------------------------------------------------------------------------------------------------
# The helper


def test_draw_blocked_draws_grey_squares_and_leaves_the_axes_alone():
    fig, ax = plt.subplots(figsize=(4, 4))
    ax.set_xlim(0, 12)
    ax.set_ylim(0, 12)
    ax.set_aspect("equal")
    image = viz.draw_blocked(ax, _blocked_mask(), 1.0, (0.0, 0.0))
    assert image is not None and image.get_label() == "blocked" and image.get_gid() == "blocked"
    assert image.get_extent() == (0.0, 12.0, 0.0, 12.0)
    assert ax.get_xlim() == (0, 12) and ax.get_ylim() == (0, 12)
    _assert_drawn(fig, ax)
    handle = viz.blocked_handle()
    assert handle.get_label() == "blocked"
    assert matplotlib.colors.to_hex(handle.get_facecolor()) == viz.PALETTE["blocked"] == "#404040"
    plt.close(fig)


def test_draw_blocked_maps_cells_with_cell_size_and_origin():
    fig, ax = plt.subplots()
    image = viz.draw_blocked(ax, _blocked_mask(), 0.5, (-2.0, 3.0))
    assert image.get_extent() == (-2.0, 4.0, 3.0, 9.0)
    plt.close(fig)


def test_draw_blocked_draws_nothing_without_blocked_cells():
    fig, ax = plt.subplots()
    assert viz.draw_blocked(ax, None, 1.0, (0.0, 0.0)) is None
    assert viz.draw_blocked(ax, np.zeros((12, 12), bool), 1.0, (0.0, 0.0)) is None
    assert not ax.get_images() and not ax.collections
    with pytest.raises(ValueError, match="bool \\[H, W\\]"):
        viz.draw_blocked(ax, np.ones(5, bool), 1.0, (0.0, 0.0))
    plt.close(fig)


def test_blocked_of_reads_the_scene():
    np.testing.assert_array_equal(viz.blocked_of(_scene()), _blocked_mask())
    assert not viz.blocked_of(_scene(blocked=False)).any()


def test_the_helpers_are_exported():
    import jaxplan.transport as transport

    for name in ("draw_blocked", "blocked_handle", "blocked_of"):
        assert name in transport.__all__ and getattr(transport, name) is getattr(viz, name)


# --------------------------------------------------------------------------------------------------
# The figures


def test_scene_has_inf_dist_on_the_block():
    """The premise of the inf checks below."""
    dist = np.asarray(_scene().dist)
    assert np.isinf(dist[BLOCK]).all() and np.isfinite(dist[~_blocked_mask()]).all()


def test_plot_fabric_draws_blocked_cells(planned):
    scene, fabric, connectors, _ = planned
    # sources around the block: their paths and fallbacks use dist and tvec next to inf cells
    sources = [[2, 5], [8, 2], [3, 4], [1, 1]]
    fig = viz.plot_fabric(scene, fabric, connectors, path_sources=sources)
    ax = fig.axes[0]
    _assert_drawn(fig, ax)
    assert "blocked" in _legend_labels(ax)
    for line in ax.lines:
        assert np.isfinite(np.asarray(line.get_xydata(), float)).all()
    heat = ax.get_images()[0]
    assert np.isfinite(heat.get_clim()).all()
    plt.close(fig)


def test_plot_fabric_without_blocked_cells_has_no_blocked_layer():
    from jaxplan.transport import FabricParams, build_fabric

    scene = _scene(blocked=False)
    fig = viz.plot_fabric(scene, build_fabric(scene, FabricParams()))
    ax = fig.axes[0]
    assert not [im for im in ax.get_images() if im.get_gid() == "blocked"]
    assert "blocked" not in _legend_labels(ax)
    plt.close(fig)


def test_plot_fabric_colour_scale_ignores_inf_heat(planned):
    """A heat map holding inf (as ``dist`` does on blocked cells) is drawn with a finite scale."""
    scene, fabric, _, _ = planned
    heat = np.asarray(fabric.heat, np.float64).copy()
    heat[_blocked_mask()] = np.inf

    class Inf:
        def __getattr__(self, name):
            return heat if name == "heat" else getattr(fabric, name)

    fig = viz.plot_fabric(scene, Inf())
    finite_top = float(np.asarray(fabric.heat).max())
    assert fig.axes[0].get_images()[0].get_clim() == (0.0, pytest.approx(finite_top if finite_top > 0 else 1.0))
    _assert_drawn(fig, fig.axes[0])
    plt.close(fig)


def test_plot_episode_draws_blocked_cells(planned):
    scene, _, _, episode = planned
    fig = viz.plot_episode(scene, episode)
    ax = fig.axes[1]   # the final counts
    _assert_drawn(fig, ax)
    assert _legend_labels(ax) == ["blocked"]
    plt.close(fig)


def test_animate_episode_draws_blocked_cells(planned, tmp_path, monkeypatch):
    from PIL import Image

    scene, _, _, episode = planned
    seen = {}
    real = viz.save_animation

    def spy(fig, draw, n, path, *, fps, dpi):
        seen.update(ax=fig.axes[0], fig_dpi=fig.dpi, dpi=dpi)
        real(fig, draw, n, path, fps=fps, dpi=dpi)

    monkeypatch.setattr(viz, "save_animation", spy)
    viz.animate_episode(scene, episode, tmp_path / "episode.gif", fps=4, dpi=60)
    ax = seen["ax"]
    assert [im for im in ax.get_images() if im.get_gid() == "blocked"]
    with Image.open(tmp_path / "episode.gif") as gif:
        assert gif.n_frames == len(episode.frames)
        for k in (0, gif.n_frames - 1):
            gif.seek(k)
            rgb = np.asarray(gif.convert("RGB"))
            scale = seen["dpi"] / seen["fig_dpi"]
            assert np.abs(_pixel(rgb, ax, BLOCKED_CELL, scale) - GREY).max() <= 8     # GIF palette
            assert np.abs(_pixel(rgb, ax, FREE_CELL, scale) - GREY).max() > 20


def test_plot_check_draws_blocked_cells():
    pytest.importorskip("mujoco")
    from jaxplan.transport.physics import bridge, plot_check

    scene = _scene()
    _, routes, _ = bridge.plan_routes(scene, n_routes=1)
    check = bridge.check_routes(scene, routes, n_ticks=3, backend="c")
    fig = plot_check(scene, check)
    for ax in fig.axes:
        if ax.get_label() == "<colorbar>":
            continue
        _assert_drawn(fig, ax)
        assert "blocked" in _legend_labels(ax)
    plt.close(fig)
