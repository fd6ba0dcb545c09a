"""MJX-Warp (Simulator backend="warp") against the C engine on the tiny push scene, on the CPU."""
import numpy as np
import pytest

from jaxplan.physics.rollout import Simulator, default_backend, warp_available
from jaxplan.pusharound.physics import build_push_world
from jaxplan.pusharound.push import make_push_simulator, simulate_pushes, stack_tasks
from tests.pusharound.test_physics import _scene, _task


def test_auto_names_its_pick():
    w = build_push_world(_scene())
    sim = make_push_simulator(w, "auto")
    assert sim.auto and sim.backend == default_backend(w.model) and sim.backend in ("c", "mjx", "warp")
    with pytest.raises(ValueError, match="backend"):
        Simulator(w.model, lambda *a: a, backend="gpu")


@pytest.mark.skipif(not warp_available(), reason="warp-lang not installed (pip install 'jaxplan[warp]')")
def test_warp_agrees_with_c_engine():
    """A clean push and a push into the wall: same verdicts; final box pose within 1 cm / 2 degrees."""
    w = build_push_world(_scene())
    batch = stack_tasks([_task(w, (1, 0), (0.3, 0, 0)), _task(w, (1, 0), (0.6, 0, 0))])
    c = simulate_pushes(w, batch, sim=make_push_simulator(w, "c"))
    wp = simulate_pushes(w, batch, sim=make_push_simulator(w, "warp"))
    np.testing.assert_array_equal(wp.valid, c.valid)
    np.testing.assert_array_equal(wp.hit_fixed, c.hit_fixed)
    assert list(c.valid) == [True, False]
    np.testing.assert_allclose(wp.poses[:, 0, :2], c.poses[:, 0, :2], atol=0.01)
    np.testing.assert_allclose(wp.poses[:, 0, 2], c.poses[:, 0, 2], atol=np.deg2rad(2.0))
