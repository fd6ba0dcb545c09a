"""The fleet report on a hand-made FleetRun (2 rovers, 10 x 10 scene, 2 pushes): numbers and files."""
from __future__ import annotations

import json

import matplotlib
import numpy as np
import pytest

from jaxplan.core.outputs import RunFolder, read_manifest
from jaxplan.fleet import FleetRun
from jaxplan.fleet import report as R
from jaxplan.transport.scene import Scene, circle

matplotlib.use("Agg")

T = 6


def _scene(obj=None):
    obj = np.zeros((10, 10)) if obj is None else obj
    return Scene.from_arrays(obj, circle((8.5, 8.5), 1.2), name="tiny")


def _fake_run(*, frames=True, plan_ms=(1.0, 3.0), **changes) -> FleetRun:
    """Rover 0 walks right along row 1 and pushes once (steps 1-3); rover 1 walks up column 1 and
    pushes once (steps 3-5). Initial outside mass 20; 12 delivered by step 5, 19 by step 6."""
    obj = np.zeros((10, 10))
    obj[1, 2:6] = 3.0
    obj[3:5, 1] = 4.0
    scene = _scene(obj)
    pos = np.zeros((T + 1, 2, 2), np.int32)
    pos[:, 0] = [[1, min(c, 5)] for c in range(1, T + 2)]
    pos[:, 1] = [[min(r, 5), 1] for r in range(1, T + 2)]
    delivered = np.array([0, 0, 0, 6, 6, 12, 19], float)
    pushes = [
        {"rover": 0, "first_step": 1, "last_step": 3, "cells": np.array([[1, 2], [1, 3], [1, 4]]),
         "collected": np.float32(8.0), "delivered": np.float32(6.0), "spilled": np.float32(2.0), "mode": "deliver"},
        {"rover": 1, "first_step": 3, "last_step": 5, "cells": [[3, 1], [4, 1]],
         "collected": 7.0, "delivered": 6.0, "spilled": 1.0, "mode": "rearrange"},
    ]
    routes = [[np.array([[1, 2], [1, 3], [1, 4]]), None], [None, np.array([[3, 1], [4, 1]])], [None, None]]
    rec = [{"obj": obj.astype(np.float32) * (1 - k / T), "heat": np.full((10, 10), k, np.float32),
            "highways": np.eye(10, dtype=bool), "routes": routes[min(k // 2, 2)]} for k in range(T)]
    fields = dict(
        scene=scene, final_scene=scene.with_obj(obj * 0.05), n_rovers=2, strategy="coordinated", steps=T, pos=pos,
        delivered=delivered, outside=20.0 - delivered, initial_mass=20.0, initial_outside=20.0, pushes=pushes,
        rover_pushes=np.array([1, 1], np.int32), idle_steps=np.array([3, 1], np.int32), plan_ms=list(plan_ms),
        conflicts=0, stop_reason="done", message="all delivered", frames=rec if frames else None,
        step_ms=[p + 1.0 for p in plan_ms], refresh_ms=[1.0] * len(plan_ms), full_build_ms=5.0 if plan_ms else None)
    fields.update(changes)
    return FleetRun(**fields)


def test_summary_numbers():
    s = R.summary_of(_fake_run())
    assert (s["n_rovers"], s["strategy"], s["steps"], s["pushes"]) == (2, "coordinated", T, 2)
    assert (s["delivered"], s["spilled"], s["remaining"]) == (19.0, 3.0, 1.0)
    assert (s["T50"], s["T90"]) == (5, 6)     # 12 >= 10 first at step 5; 19 >= 18 at step 6
    assert s["pushes_per_rover"] == [1, 1]
    assert s["idle_fraction"] == [0.5, 1 / 6]
    assert s["plan_ms"]["median"] == pytest.approx(2.0) and s["plan_ms"]["p95"] == pytest.approx(2.9)
    assert s["step_ms"] == {"median": 3.0, "p95": pytest.approx(3.9)} and s["refresh_ms"]["median"] == 1.0
    assert s["full_build_ms"] == 5.0
    assert (s["conflicts"], s["stop_reason"], s["message"]) == (0, "done", "all delivered")
    assert s["delivered_per_rover_step"] == pytest.approx(19.0 / 12)
    assert s["scene"] == "tiny" and s["unreachable_mass"] == 0.0
    json.dumps(s, allow_nan=False)   # plain JSON types only


def test_summary_names_the_given_scene_and_counts_mass_cut_off_by_blocked_cells():
    # the run's scene is the compiled step's copy, which has no name: FleetRun.scene_name keeps it
    obj = np.zeros((10, 10))
    obj[1, 2:6] = 3.0
    obj[0, 9] = 1.5                       # cut off: (0, 8) and (1, 9) are blocked, (0, 9) is a corner
    blocked = np.zeros((10, 10), bool)
    blocked[0, 8] = blocked[1, 9] = blocked[1, 8] = True
    scene = Scene.from_arrays(obj, circle((8.5, 8.5), 1.2), blocked=blocked)
    run = _fake_run(scene=scene, final_scene=scene, scene_name="walls.npz")
    s = R.summary_of(run)
    assert s["scene"] == "walls.npz" and s["unreachable_mass"] == 1.5
    assert R.summary_of(_fake_run(scene=scene, final_scene=scene))["scene"] is None
    assert R.summary_of(_fake_run(scene_name="site"))["scene"] == "site"


def test_summary_without_events_or_reaching_t90():
    delivered = np.array([2, 2, 2, 4, 6, 9, 12], float)   # 10 gained of 20: T50 at step 6, no T90
    s = R.summary_of(_fake_run(plan_ms=(), delivered=delivered, outside=22.0 - delivered))
    assert (s["T50"], s["T90"]) == (6, None)
    assert s["delivered"] == 10.0
    assert s["plan_ms"] == s["step_ms"] == s["refresh_ms"] == {"median": None, "p95": None}
    assert s["full_build_ms"] is None


def test_a_run_whose_arrays_disagree_is_a_named_error():
    with pytest.raises(ValueError, match=r"FleetRun.pos: shape \(6, 2, 2\)"):
        R.summary_of(_fake_run(pos=np.zeros((T, 2, 2), np.int32)))


def test_trajectory_and_pushes():
    run = _fake_run()
    arrays = R.trajectory_arrays(run)
    assert arrays["pos"].dtype == np.int32 and arrays["pos"].shape == (T + 1, 2, 2)
    assert arrays["delivered"].dtype == np.float64 and arrays["outside"].shape == (T + 1,)
    assert arrays["initial_mass"].shape == () and float(arrays["initial_mass"]) == 20.0
    for key, scene in (("obj_initial", run.scene), ("obj_final", run.final_scene)):   # f32[H, W], rows = y
        assert arrays[key].dtype == np.float32 and arrays[key].shape == (10, 10)
        np.testing.assert_array_equal(arrays[key], np.asarray(scene.obj))
    assert arrays["obj_initial"][1, 2] == 3.0 and arrays["obj_initial"][2, 1] == 0.0     # (row, col)
    assert str(arrays["convention"]) == R.TRAJECTORY_CONVENTION == "cells are (row, col); rows = y, columns = x"
    records = R.pushes_records(run)
    assert [r["rover"] for r in records] == [0, 1]
    assert records[0]["cells"] == [[1, 2], [1, 3], [1, 4]] and records[1]["mode"] == "rearrange"
    assert type(records[0]["delivered"]) is float
    json.dumps(records, allow_nan=False)


@pytest.mark.parametrize("n_frames, steps, most, expected", [
    (6, 6, 10, [(i, i + 1) for i in range(6)]),       # one frame after each step
    (7, 6, 10, [(i, i) for i in range(7)]),           # the start recorded too
    (100, 100, 5, [(0, 1), (25, 26), (50, 51), (74, 75), (99, 100)]),
    (0, 6, 10, []),
])
def test_frame_steps_subsample_evenly_and_end_on_the_last_step(n_frames, steps, most, expected):
    assert R.frame_steps(n_frames, steps, most) == expected


def test_write_fleet_outputs(tmp_path):
    from PIL import Image

    run = _fake_run()
    with RunFolder(tmp_path / "out", "fleet") as folder:
        paths = R.write_fleet_outputs(run, folder, animate=True, fps=5, max_frames=4, extra_summary={"seed": 0})
    out = tmp_path / "out"
    assert sorted(paths) == sorted(R.FLEET_OUTPUTS)
    manifest = read_manifest(out)
    assert manifest["status"] == "complete" and sorted(manifest["files"]) == sorted(R.FLEET_OUTPUTS)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["T90"] == 6 and summary["seed"] == 0
    assert summary["scene"] == "tiny" and summary["unreachable_mass"] == 0.0
    with np.load(out / "trajectory.npz") as npz:      # no pickles: the convention is a plain string array
        np.testing.assert_array_equal(npz["pos"], run.pos)
        assert npz["delivered"].dtype == np.float64
        np.testing.assert_array_equal(npz["obj_initial"], np.asarray(run.scene.obj, np.float32))
        np.testing.assert_array_equal(npz["obj_final"], np.asarray(run.final_scene.obj, np.float32))
        assert str(npz["convention"]) == R.TRAJECTORY_CONVENTION
    assert len(json.loads((out / "pushes.json").read_text())) == 2
    assert Image.open(out / "fleet.png").size[0] > 0
    with Image.open(out / "fleet.gif") as gif:
        assert gif.n_frames == 4


def test_no_animation_without_frames_or_when_not_asked(tmp_path):
    for name, run, animate in (("a", _fake_run(frames=False), True), ("b", _fake_run(), False)):
        with RunFolder(tmp_path / name, "fleet") as folder:
            paths = R.write_fleet_outputs(run, folder, animate=animate, fps=5)
        assert "fleet.gif" not in paths and not (tmp_path / name / "fleet.gif").exists()
        assert (tmp_path / name / "fleet.png").is_file()


def test_extra_summary_cannot_replace_the_runs_numbers(tmp_path):
    with RunFolder(tmp_path / "out", "fleet") as folder, pytest.raises(ValueError, match="T90"):
        R.write_fleet_outputs(_fake_run(), folder, animate=False, fps=5, extra_summary={"T90": 1})


def _panels(fig) -> dict:
    """fleet.png's panels by name (their gid; the colour bars' axes have none)."""
    return {ax.get_gid(): ax for ax in fig.axes if ax.get_gid()}


def _image_data(ax) -> np.ndarray:
    """The first image of ``ax`` (the counts or the traffic, drawn first) as f64 with NaN where masked."""
    return np.ma.filled(np.ma.asarray(ax.get_images()[0].get_array(), np.float64), np.nan)


def test_traffic_counts_count_the_moves_into_each_cell():
    expected = np.zeros((10, 10), np.int64)
    expected[1, 2:6] = 1          # rover 0 drives right along row 1, then waits at (1, 5)
    expected[2:6, 1] = 1          # rover 1 drives up column 1, then waits at (5, 1)
    np.testing.assert_array_equal(R.traffic_counts(_fake_run()), expected)
    pos = np.zeros((T + 1, 1, 2), np.int32)     # back and forth between (2, 2) and (2, 3), waiting once
    pos[:, 0] = [[2, 2], [2, 3], [2, 2], [2, 2], [2, 3], [2, 2], [2, 3]]
    counts = R.traffic_counts(_fake_run(n_rovers=1, pos=pos, rover_pushes=np.zeros(1, np.int32),
                                        idle_steps=np.zeros(1, np.int32)))
    assert (counts[2, 2], counts[2, 3], counts.sum()) == (2, 3, 5)


def test_plot_fleet_shows_mass_t50_t90_piles_traffic_and_final_counts():
    import matplotlib.pyplot as plt

    run = _fake_run()
    fig = R.plot_fleet(run)
    panels = _panels(fig)
    assert list(panels) == list(R.FIGURE_PANELS) == ["mass", "start", "traffic", "final"]
    mass = panels["mass"]
    assert (mass.get_xlabel(), mass.get_ylabel()) == ("step", "mass (objects)")
    labels = {t.get_gid(): t.get_text() for t in mass.texts}
    assert labels == {"T50": "T50 = 5", "T90": "T90 = 6"}          # summary_of's T50 and T90, drawn
    assert {"T50 = 5 steps (50% delivered)", "T90 = 6 steps (90% delivered)"} <= set(_legend_texts(mass))
    for name in ("start", "traffic", "final"):
        ax = panels[name]
        assert ax.get_title() and ax.get_xlabel() == "x (world units)" and ax.get_ylabel() == "y (world units, up)"
        assert "target" in _legend_texts(ax)
    target = np.asarray(run.scene.target_mask)
    for name, scene in (("start", run.scene), ("final", run.final_scene)):     # counts, targets off the scale
        np.testing.assert_array_equal(_image_data(panels[name]), np.where(target, np.nan, np.asarray(scene.obj)))
    traffic = R.traffic_counts(run)
    np.testing.assert_array_equal(_image_data(panels["traffic"]), np.where(traffic > 0, traffic, np.nan))
    assert "8 rover moves" in panels["traffic"].get_title()
    # the rovers: starts on "start", final cells on "final" (cell centres, rows = y)
    for name, step in (("start", 0), ("final", T)):
        (dots,) = panels[name].collections[-1:]
        np.testing.assert_allclose(dots.get_offsets(), run.pos[step][:, ::-1] + 0.5)
        assert any(label.startswith("rover") for label in _legend_texts(panels[name]))
    colorbars = [ax.get_ylabel() for ax in fig.axes if not ax.get_gid()]
    assert sorted(colorbars) == ["objects per cell", "objects per cell", "rover moves into the cell (count)"]
    plt.close(fig)


def test_plot_fleet_says_when_t90_is_not_reached():
    import matplotlib.pyplot as plt

    delivered = np.array([2, 2, 2, 4, 6, 9, 12], float)   # T50 at step 6, no T90
    fig = R.plot_fleet(_fake_run(delivered=delivered, outside=22.0 - delivered))
    mass = _panels(fig)["mass"]
    assert {t.get_gid(): t.get_text() for t in mass.texts} == {"T50": "T50 = 6"}
    assert "T90 (90% delivered): not reached in 6 steps" in _legend_texts(mass)
    plt.close(fig)


def _spy_animation(monkeypatch) -> dict:
    """Record the animated figure's map axes and the scale of the written frames to the figure."""
    seen = {}
    real = R.save_animation

    def spy(fig, draw, n, path, *, fps, dpi):
        seen.update(ax=fig.axes[0], scale=dpi / fig.dpi)
        real(fig, draw, n, path, fps=fps, dpi=dpi)

    monkeypatch.setattr(R, "save_animation", spy)
    return seen


def _pixel(rgb, ax, cell, scale):
    x, y = ax.transData.transform((cell[1] + 0.5, cell[0] + 0.5)) * scale
    return rgb[int(round(rgb.shape[0] - y)), int(round(x)), :3].astype(int)


def test_animate_fleet_colours_the_mass(tmp_path, monkeypatch):
    from matplotlib import colormaps
    from PIL import Image

    seen = _spy_animation(monkeypatch)
    run = _fake_run()       # frame k holds the counts times (1 - k / 6); frames 0, 2, 5 are drawn
    assert R.animate_fleet(run, tmp_path / "fleet.gif", fps=5, max_frames=3, dpi=60) == 3
    ax, scale = seen["ax"], seen["scale"]
    assert _legend_texts(ax) == ["rover (index)", "current route (rover's colour)", "target"]
    cmap = colormaps[R.MASS_CMAP]
    heavy, empty = (4, 1), (8, 3)       # 4 objects in frame 0 (the scale's top), and a cell never holding any
    with Image.open(tmp_path / "fleet.gif") as gif:
        for k, frame in ((0, 0), (2, 5)):
            gif.seek(k)
            rgb = np.asarray(gif.convert("RGB"))
            expected = np.asarray(cmap(4.0 * (1 - frame / T) / 4.0)[:3]) * 255
            assert np.abs(_pixel(rgb, ax, heavy, scale) - expected).max() <= 12, k
            assert np.abs(_pixel(rgb, ax, empty, scale) - np.asarray(cmap(0.0)[:3]) * 255).max() <= 12, k
        gif.seek(0)
        first = _pixel(np.asarray(gif.convert("RGB")), ax, heavy, scale)
        gif.seek(2)
        assert first.sum() < _pixel(np.asarray(gif.convert("RGB")), ax, heavy, scale).sum() - 100   # lighter


def test_plot_and_animation_accept_many_rovers(tmp_path):
    n = 12   # beyond the labelled and tab10 range
    pos = np.stack([np.stack([np.full(T + 1, i % 10), np.arange(T + 1) % 10], -1) for i in range(n)], 1)
    frames = [{"obj": np.zeros((10, 10), np.float32), "heat": np.zeros((10, 10), np.float32),
               "highways": np.zeros((10, 10), bool), "routes": [None] * n} for _ in range(T + 1)]
    run = _fake_run(n_rovers=n, pos=pos.astype(np.int32), rover_pushes=np.zeros(n, np.int32),
                    idle_steps=np.full(n, T, np.int32), frames=frames)
    import matplotlib.pyplot as plt

    plt.close(R.plot_fleet(run))
    calls = []
    assert R.animate_fleet(run, tmp_path / "many.gif", fps=5, max_frames=3, progress=lambda i, k: calls.append(i)) == 3
    assert calls == [1, 2, 3] and (tmp_path / "many.gif").stat().st_size > 0


# --------------------------------------------------------------------------------------------------
# Blocked cells (issue 45): fleet.png and fleet.gif draw them as solid dark-grey squares. The run is
# hand-made (no rover or material on the block): these test the drawing, not the fleet's run.

_BLOCK = (slice(5, 8), slice(4, 7))
_BLOCKED_CELL, _FREE_CELL = (6, 5), (9, 1)
_GREY = np.array([0x40, 0x40, 0x40])


def _blocked_run(**changes) -> FleetRun:
    run = _fake_run()
    blocked = np.zeros((10, 10), bool)
    blocked[_BLOCK] = True
    scene = Scene.from_arrays(np.asarray(run.scene.obj), circle((8.5, 8.5), 1.2), name="tiny", blocked=blocked)
    return _fake_run(scene=scene, final_scene=scene.with_obj(np.asarray(run.final_scene.obj)), **changes)


def _blocked_pixels_ok(rgb, ax, scale=1.0, tol=3):
    """The rendered image ``rgb`` of ``ax``'s figure (at ``scale`` x its dpi) is dark grey at a blocked
    cell's centre and not at a free cell's."""
    def pixel(cell):
        x, y = ax.transData.transform((cell[1] + 0.5, cell[0] + 0.5)) * scale
        return rgb[int(round(rgb.shape[0] - y)), int(round(x)), :3].astype(int)

    return np.abs(pixel(_BLOCKED_CELL) - _GREY).max() <= tol and np.abs(pixel(_FREE_CELL) - _GREY).max() > 20


def _blocked_layer(ax):
    return [im for im in ax.get_images() if im.get_gid() == "blocked"]


def _legend_texts(ax) -> list[str]:
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_plot_fleet_draws_blocked_cells():
    import io

    import matplotlib.pyplot as plt
    from PIL import Image

    fig = R.plot_fleet(_blocked_run())
    panels = _panels(fig)
    expected = np.zeros((10, 10), bool)
    expected[_BLOCK] = True
    for name in ("start", "traffic", "final"):          # every map panel
        (layer,) = _blocked_layer(panels[name])
        np.testing.assert_array_equal(np.asarray(layer.get_array())[..., 3] > 0, expected)
        assert "blocked" in _legend_texts(panels[name])
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    rgb = np.asarray(Image.open(buf).convert("RGB"))
    assert _blocked_pixels_ok(rgb, panels["final"]) and _blocked_pixels_ok(rgb, panels["start"])
    plt.close(fig)
    # a scene without blocked cells: no layer, no "blocked" in the maps' legends
    fig = R.plot_fleet(_fake_run())
    for name in ("start", "traffic", "final"):
        assert not _blocked_layer(_panels(fig)[name]) and "blocked" not in _legend_texts(_panels(fig)[name])
    plt.close(fig)


def test_animate_fleet_draws_blocked_cells(tmp_path, monkeypatch):
    from PIL import Image

    seen = _spy_animation(monkeypatch)
    assert R.animate_fleet(_blocked_run(), tmp_path / "fleet.gif", fps=5, max_frames=3, dpi=60) == 3
    assert _blocked_layer(seen["ax"]) and _legend_texts(seen["ax"])[-1] == "blocked"
    with Image.open(tmp_path / "fleet.gif") as gif:
        for k in range(gif.n_frames):
            gif.seek(k)
            assert _blocked_pixels_ok(np.asarray(gif.convert("RGB")), seen["ax"], seen["scale"], tol=8), k


def test_write_fleet_outputs_with_blocked_cells(tmp_path):
    with RunFolder(tmp_path / "out", "fleet") as folder:
        paths = R.write_fleet_outputs(_blocked_run(), folder, animate=True, fps=5, max_frames=2)
    assert sorted(paths) == sorted(R.FLEET_OUTPUTS)
    assert read_manifest(tmp_path / "out")["status"] == "complete"
