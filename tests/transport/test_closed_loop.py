"""An episode closed through physics (jaxplan.transport.physics.closed_loop) on a tiny scene: mass is
kept, each push's prediction is the grid's push from the counts physics left, the next push is
planned from those counts, and the figure, GIF and CLI outputs are written."""
from __future__ import annotations

import json

import numpy as np
import pytest

from jaxplan.cli import main
from jaxplan.transport import execute_push, random_scene
from jaxplan.transport.physics import (
    animate_closed_loop,
    grid_episode,
    plot_closed_loop,
    run_closed_loop,
)
from jaxplan.transport.spillage import LEARNED_FIT, evaluator_for

PUSHES = 2


@pytest.fixture(scope="module")
def scene():
    return random_scene(4, (9, 9), 0.5, layout="piles")


@pytest.fixture(scope="module")
def loop(scene):
    return run_closed_loop(scene, max_pushes=PUSHES)


def test_mass_is_kept_and_each_push_is_planned_from_what_physics_left(scene, loop):
    assert len(loop.pushes) == PUSHES and loop.stop_reason == "max pushes"
    assert loop.obj.shape == (PUSHES + 1, *scene.shape)
    target = np.asarray(scene.target_mask)
    lost = 0.0
    for k, push in enumerate(loop.pushes):
        lost += push["lost"]
        assert loop.obj[k + 1].sum() + lost == pytest.approx(loop.obj[0].sum(), abs=1e-6)
        gain = loop.obj[k + 1][target].sum() - loop.obj[k][target].sum()
        assert push["delivered"] == pytest.approx(gain, abs=1e-6)
        assert push["delivered"] <= push["collected"] + 1e-6
    # the second push's prediction is the grid's push of its route from the counts physics left
    counts = scene.with_obj(loop.obj[1].astype(np.float32))
    cells = np.asarray(loop.pushes[1]["cells"])
    assert counts.obj[cells[0, 0], cells[0, 1]] > 0           # its source holds material after physics
    np.testing.assert_allclose(loop.delivered, np.concatenate([[0], np.cumsum([p["delivered"] for p in loop.pushes])]))
    assert np.all(np.diff(loop.predicted) >= 0)


def test_the_first_prediction_is_the_grid_only_episodes_first_push(scene, loop):
    grid = grid_episode(scene, max_pushes=PUSHES)
    assert grid.shape == (PUSHES + 1,) and grid[0] == 0.0
    assert loop.pushes[0]["predicted"] == pytest.approx(grid[1], rel=1e-5)


def test_figure_and_animation_are_written(scene, loop, tmp_path):
    fig = plot_closed_loop(loop, grid_episode(scene, max_pushes=1))
    assert len(fig.axes[0].lines) == 3
    animate_closed_loop(scene, loop, tmp_path / "run.gif", fps=4, dpi=40)
    assert (tmp_path / "run.gif").read_bytes()[:3] == b"GIF"
    assert len(loop.frames) == PUSHES
    assert all(f.ndim == 3 and f.shape[2] == 2 and f.shape[1] >= 2 for f in loop.frames)   # particles + rover


def test_a_bad_budget_is_refused(scene):
    with pytest.raises(ValueError, match="max_pushes: must be an int >= 1"):
        run_closed_loop(scene, max_pushes=0)


def test_execute_push_is_the_prediction_of_the_first_push(scene, loop):
    # the loop's prediction goes through the model LEARNED_FIT is for, not the curvature default
    from jaxplan.transport import EpisodeParams, FabricParams, build_fabric, default_walk_cap, plan_episode_tick

    evaluator = evaluator_for(LEARNED_FIT)
    fabric = build_fabric(scene, FabricParams())
    plan, _ = plan_episode_tick(scene, FabricParams(), EpisodeParams(), LEARNED_FIT, fabric,
                                default_walk_cap(scene.shape), evaluator)
    _, push = execute_push(scene, plan.route, LEARNED_FIT, evaluator)
    assert loop.pushes[0]["predicted"] == pytest.approx(float(push.delivered), rel=1e-6)


def test_cli_episode_physics_writes_its_files(scene, tmp_path, capsys):
    path = tmp_path / "scene.npz"
    scene.save(path)          # the module's scene: its programs are compiled already
    out = tmp_path / "out"
    assert main(["episode", "--scene", str(path), "--physics", "--max-pushes", "1", "--no-animation",
                 "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["spill"]["model"] == "LearnedSpillParams" and len(summary["pushes"]) == 1
    assert set(summary["cumulative"]) == {"physics", "predicted", "grid_only"}
    assert summary["final"]["delivered"] == summary["cumulative"]["physics"][-1]
    assert (out / "closed_loop.png").read_bytes()[:4] == b"\x89PNG"
    with np.load(out / "counts.npz") as counts:
        assert counts["obj"].shape == (2, *scene.shape)
    assert "pushes in physics" in capsys.readouterr().out
