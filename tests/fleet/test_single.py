"""One rover with the single-rover rule (``independent``, N = 1) runs ``run_episode``'s pushes: the
same routes, cell by cell, the same delivered and spilled mass per push, the same kind of stop."""
from __future__ import annotations

import numpy as np
import pytest

from jaxplan import FabricParams, SpillParams, run_episode
from jaxplan.fleet import run_fleet
from jaxplan.transport.episode import EpisodeParams
from tests.fleet._sites import site

SHAPE = (16, 16)
PARAMS = FabricParams()
SPILL = SpillParams(lam=0.1)
CASES = (   # (seed, layout, stop_fraction, max_pushes): ends "done", "budget", "done" on two targets,
    (1, "uniform", 0.6, 20),         # then on sites with buildings: random ones and a map-made one
    (2, "piles", 0.02, 10),
    (3, "two_targets", 0.5, 20),
    (4, "buildings", 0.3, 20),
    (5, "map", 0.3, 20),
)


@pytest.fixture(scope="module", params=CASES, ids=lambda c: f"{c[1]}-{c[0]}")
def pair(request):
    seed, layout, fraction, pushes = request.param
    scene = site(seed, SHAPE, layout)
    ep = EpisodeParams(max_pushes=pushes, stop_fraction=fraction, rebuild="full", rearrange_margin=0.0)
    return (run_episode(scene, PARAMS, SPILL, ep, record=True),
            run_fleet(scene, 1, "independent", PARAMS, SPILL, ep, max_steps=2_000, record=True))


def test_one_independent_rover_pushes_the_episodes_routes(pair):
    episode, fleet = pair
    assert len(fleet.pushes) == episode.n_pushes >= 3
    for k, (frame, push) in enumerate(zip(episode.frames, fleet.pushes)):
        np.testing.assert_array_equal(np.asarray(push["cells"]), frame["route"], err_msg=f"push {k}")
        assert push["mode"] == ("deliver", "rearrange")[frame["mode"]]
    delivered = [p["delivered"] for p in fleet.pushes]
    np.testing.assert_allclose(delivered, episode.push_delivered, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose([p["spilled"] for p in fleet.pushes], episode.push_spilled, rtol=1e-5, atol=1e-3)
    assert fleet.stop_reason == episode.stop_reason
    np.testing.assert_allclose(np.asarray(fleet.final_scene.obj), episode.final_obj, atol=1e-3)
    # the compiled step's scene copy has no name; the run keeps the given scene's
    assert fleet.scene.name is None and fleet.scene_name


def test_the_rover_drives_one_cell_a_step_and_stays_clear(pair):
    _, fleet = pair
    assert fleet.conflicts == 0 and fleet.kernel_conflicts == 0
    assert np.all(np.abs(np.diff(fleet.pos, axis=0)).max(-1) <= 1)
    # the mass inside and outside the targets always adds up to the initial mass, exactly
    np.testing.assert_array_equal(fleet.delivered + fleet.outside, np.full(fleet.steps + 1, fleet.initial_mass))
    for push in fleet.pushes:    # the rover stands on the route's last cell when its push is applied
        assert tuple(fleet.pos[push["last_step"], 0]) == tuple(push["cells"][-1])


def test_frames_follow_the_run(pair):
    _, fleet = pair
    assert len(fleet.frames) == fleet.steps + 1 and fleet.frames[0]["routes"] == [None]
    shape = np.asarray(fleet.scene.obj).shape
    assert all(f["obj"].shape == f["heat"].shape == f["highways"].shape == shape for f in fleet.frames)
    for push in fleet.pushes:    # every frame of a task shows its route
        for t in range(push["first_step"], push["last_step"] + 1):
            np.testing.assert_array_equal(fleet.frames[t]["routes"][0], push["cells"])
    np.testing.assert_array_equal(fleet.frames[-1]["obj"], np.asarray(fleet.final_scene.obj))
