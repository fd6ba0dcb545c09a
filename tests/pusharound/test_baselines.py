"""PushAround benchmark: seeded scene generators and the Table I baselines (the harness itself:
tests/experiments/test_table1.py)."""
import numpy as np
import pytest

from jaxplan.pusharound.baselines import (
    BASELINES,
    BaselineConfig,
    dfs_wccg,
    execute_open_loop,
    schedule_duration,
    sl_push_offline,
)
from jaxplan.pusharound.generators import corridor_scene, dense_scene, density_scene, nominal_scene
from jaxplan.pusharound.physics import build_push_world
from jaxplan.pusharound.push import make_push_simulator
from jaxplan.pusharound.scene import validate_scene
from jaxplan.pusharound.search import ScheduledPush, SearchResult, SearchStats
from jaxplan.pusharound.wccg import build_wccg, connectivity


def _eq7(scene) -> bool:
    return connectivity(build_wccg(scene), scene.start, scene.goal).connected


def _check_scene(scene, n=None, size=None):
    validate_scene(scene)
    if n is not None:
        assert len(scene.movables) == n
    if size is not None:
        assert tuple(scene.workspace) == size
    assert np.all((scene.masses >= 5.0) & (scene.masses <= 15.0))
    assert not _eq7(scene), "generated scenes must be blocked (Eq. 7 fails)"


# ------------------------------------------------------------------------------------------ generators

def test_dense_scene_is_seeded_blocked_with_thirty_movables():
    a, b = dense_scene(3), dense_scene(3)
    assert a.to_dict() == b.to_dict()
    _check_scene(a, n=30, size=(0.0, 0.0, 8.0, 5.0))


def test_density_scene_is_nested_in_the_movable_count():
    small, large = density_scene(1, 15), density_scene(1, 25)
    assert density_scene(1, 15).to_dict() == small.to_dict()
    _check_scene(small, n=15, size=(0.0, 0.0, 8.0, 8.0))
    _check_scene(large, n=25, size=(0.0, 0.0, 8.0, 8.0))
    # The denser instance adds objects to the same layout (as the RA-L sweep).
    assert [m.pose for m in large.movables[:15]] == [m.pose for m in small.movables]


def test_nominal_and_corridor_scenes_are_blocked():
    nom = nominal_scene(2)
    assert 10 <= len(nom.movables) <= 15
    _check_scene(nom, size=(0.0, 0.0, 8.0, 5.0))
    cor = corridor_scene(5)
    assert cor.to_dict() == corridor_scene(5).to_dict()
    _check_scene(cor, n=1)


def test_generators_reject_bad_counts():
    with pytest.raises(ValueError, match="n_movables"):
        dense_scene(0, n_movables=0)
    with pytest.raises(ValueError, match="n_movables"):
        density_scene(0, n_movables=2.5)


# ------------------------------------------------------------------------------------------ baselines

@pytest.fixture(scope="module")
def corridor():
    scene = corridor_scene(0)
    world = build_push_world(scene)
    return scene, world, make_push_simulator(world, "c")


@pytest.fixture(scope="module")
def results(corridor):
    scene, world, sim = corridor
    cfg = BaselineConfig(time_limit_s=30.0, backend="c")
    return {name: fn(scene, cfg, world=world, sim=sim) for name, fn in BASELINES.items()}


def test_baselines_return_well_formed_search_results(corridor, results):
    scene, world, _ = corridor
    m, n = len(scene.movables), len(scene.robots)
    for name, res in results.items():
        assert isinstance(res, SearchResult) and isinstance(res.stats, SearchStats), name
        assert isinstance(res.success, bool) and isinstance(res.reason, str)
        assert (res.reason == "") == res.success, (name, res.reason)
        assert np.isfinite(res.stats.planning_time_s) and res.stats.planning_time_s >= 0
        assert res.stats.simulated_pushes >= 0 and res.stats.expansions >= 0
        for p in res.schedule:
            assert isinstance(p, ScheduledPush)
            assert p.poses_before.shape == (m, 3) and p.poses_after.shape == (m, 3)
            assert p.robots_before.shape == (n, 2) and p.robots_after.shape == (n, 2)
            assert p.gap == (int(p.task.movable),)
            assert np.isfinite(p.cost) or not res.success   # an invalid executed push costs inf
        if res.success:
            assert res.path is not None and _eq7(res.final_scene)
            assert schedule_duration(world, res.schedule) > 0
    # Planners without physics in planning report no simulations; the simulation-in-the-loop ones do.
    assert results["SL-Push (offline)"].stats.simulated_pushes == 0
    assert results["Rec-NAMO"].stats.simulated_pushes == 0
    assert results["SL-Push (sim)"].stats.simulated_pushes > 0


def test_dfs_wccg_solves_the_one_blocker_scene(corridor, results):
    scene, _, _ = corridor
    res = results["DFS-WCCG"]
    assert res.success and 1 <= len(res.schedule) <= BaselineConfig().dfs_depth
    assert res.stats.simulated_pushes > 0
    # The box left the opening: it moved along x (pushes along y run it into the wall).
    dx = res.final_scene.poses[0, 0] - scene.poses[0, 0]
    assert abs(dx) > 0.9


def test_open_loop_execution_of_a_clearing_push(corridor):
    scene, world, sim = corridor
    sched, poses, robots, ok, why = execute_open_loop(scene, [(0, 0.0, 1.2)], world=world, sim=sim)
    assert ok and why == ""
    assert len(sched) == 2                      # 1.2 m at 0.4 m/s for at most 2 s: two tasks
    assert poses[0, 0] - scene.poses[0, 0] > 0.9
    assert _eq7(scene.with_poses(poses))
    sched, poses, _, ok, why = execute_open_loop(scene, [(0, 0.5 * np.pi, 0.6)], world=world, sim=sim)
    assert not ok and "fixed" in why            # into the wall: physically invalid


def test_bad_baseline_config_names_the_field(corridor):
    scene, world, sim = corridor
    with pytest.raises(ValueError, match="speed"):
        dfs_wccg(scene, BaselineConfig(speed=0.0), world=world, sim=sim)
    with pytest.raises(ValueError, match="max_push_s"):
        sl_push_offline(scene, BaselineConfig(max_push_s=5.0), world=world, sim=sim)

