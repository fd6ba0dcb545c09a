"""``run_fleet`` refuses bad inputs before any work, with one ValueError naming the argument (a
TypeError for a scene that is not a Scene): the fleet's settings, the scene's leaves and counts (as
``run_episode``), and the memory the run needs."""
from __future__ import annotations

import dataclasses
import re

import jax.numpy as jnp
import numpy as np
import pytest

import jaxplan.fleet.run as fleet_run
from jaxplan import FabricParams, Scene, SpillParams
from jaxplan.fleet import FleetConfig, run_fleet
from jaxplan.fleet.state import estimate_fleet_bytes
from jaxplan.transport.episode import EpisodeParams
from tests.fleet._sites import site

SCENE = site(0, (12, 12), "uniform")


def _raw(obj=None, **changes) -> Scene:
    """A Scene from the raw constructor (no validation): ``SCENE``'s leaves, ``obj`` and ``changes``."""
    leaves = dict(obj=SCENE.obj if obj is None else jnp.asarray(obj), target_mask=SCENE.target_mask,
                  dist=SCENE.dist, tvec=SCENE.tvec, cell_size=SCENE.cell_size, origin=SCENE.origin)
    leaves.update(changes)
    return Scene(**leaves)


def _with_count(value) -> np.ndarray:
    obj = np.array(SCENE.obj)
    obj[0, 1] = value
    return obj


@pytest.mark.parametrize("kwargs, field", [
    (dict(n_rovers=0), "FleetConfig.n_rovers"),
    (dict(n_rovers=1025), "FleetConfig.n_rovers"),
    (dict(n_rovers=True), "FleetConfig.n_rovers"),
    (dict(strategy="auction"), "FleetConfig.strategy"),
    (dict(max_steps=0), "max_steps"),
    (dict(max_steps=2.5), "max_steps"),
    (dict(episode=EpisodeParams(reselect=True)), "EpisodeParams.reselect"),
    (dict(episode=EpisodeParams(max_pushes=-1)), "EpisodeParams.max_pushes"),
    (dict(params=FabricParams(temperature=0.5)), "FabricParams.temperature"),
    (dict(spill=SpillParams(lam=-1.0)), "lam"),
    (dict(n_rovers=2, starts=[[0, 0]]), "starts"),
    (dict(n_rovers=2, starts=[[0, 0], [0, 0]]), "starts"),
    (dict(n_rovers=2, starts=[[0, 0], [12, 0]]), "starts"),
    (dict(n_rovers=1, starts=[[6, 6]]), "starts"),                     # the target's centre
    (dict(config=FleetConfig(1, "coordinated", clearance=3)), "FleetConfig.clearance"),
    (dict(config=FleetConfig(2, "coordinated")), "config"),
    (dict(scene=_raw(_with_count(np.nan))), "Scene.obj: counts must be finite and >= 0; found 1 NaN"),
    (dict(scene=_raw(_with_count(-2.0))), "Scene.obj: counts must be finite and >= 0; found 1 negative"),
    (dict(scene=_raw(_with_count(np.inf))), "Scene.obj: counts must be finite and >= 0; found 1 infinite"),
    (dict(scene=_raw(target_mask=SCENE.target_mask[:, :-1])), "Scene.target_mask: shape (12, 11)"),
    (dict(scene=_raw(tvec=SCENE.tvec[:-1])), "Scene.tvec"),
])
def test_bad_inputs_are_named(kwargs, field):
    args = dict(scene=SCENE, n_rovers=1, strategy="coordinated", params=None, spill=None, episode=None,
                max_steps=100)
    args.update(kwargs)
    with pytest.raises(ValueError, match=re.escape(field)) as caught:
        run_fleet(**args)
    assert type(caught.value) is ValueError


@pytest.mark.parametrize("scene", ["site128", None, np.zeros((12, 12))])
def test_a_scene_that_is_not_a_scene_is_a_type_error(scene):
    with pytest.raises(TypeError, match="scene: expected a Scene"):
        run_fleet(scene, 1)


def test_a_fleet_too_large_for_memory_names_the_rovers_that_fit(monkeypatch):
    config = FleetConfig(4, "coordinated")
    room = estimate_fleet_bytes(SCENE.shape, dataclasses.replace(config, n_rovers=2))
    assert room < estimate_fleet_bytes(SCENE.shape, dataclasses.replace(config, n_rovers=3))
    monkeypatch.setattr(fleet_run, "available_memory_bytes", lambda: room)
    with pytest.raises(ValueError, match=r"n_rovers: a fleet of 4 rovers on a 12x12 grid needs about .* more than "
                                         r"the .* of memory available; use at most 2 rovers \(--rovers 2"):
        run_fleet(SCENE, 4, "coordinated", max_steps=10)
    assert fleet_run.check_fleet_memory(SCENE.shape, dataclasses.replace(config, n_rovers=2)) == room   # 2 fit


def test_a_coordinated_fleet_that_fits_as_independent_names_the_strategy(monkeypatch):
    shape = (512, 512)
    config = FleetConfig(1, "coordinated")
    alone = estimate_fleet_bytes(shape, FleetConfig(1, "independent"))
    assert alone < estimate_fleet_bytes(shape, config)
    with pytest.raises(ValueError, match=r"strategy: .* the independent strategy \(--strategy independent\)"):
        fleet_run.check_fleet_memory(shape, config, available=alone)


def test_a_grid_too_large_for_even_one_rover_names_the_scene(monkeypatch):
    monkeypatch.setattr(fleet_run, "available_memory_bytes", lambda: 10 ** 6)
    with pytest.raises(ValueError, match=r"scene: a fleet of 1 rovers on a 12x12 grid needs about \d+ MB \(the shared "
                                         r"fabric .*more than the 1 MB of memory available; use a smaller scene"):
        run_fleet(SCENE, 1, "independent")


def test_the_memory_estimate_grows_with_rovers_and_cells():
    config = FleetConfig(8, "independent")
    small, large = (estimate_fleet_bytes(shape, config) for shape in ((128, 128), (256, 256)))
    assert large > small
    one, eight = (estimate_fleet_bytes((512, 512), dataclasses.replace(config, n_rovers=n)) for n in (1, 8))
    assert eight - one >= 7 * 11 * 512 * 512        # at least the rovers' own grids, 11 B a cell each


def test_more_rovers_than_free_cells_are_refused():
    tiny = site(0, (3, 3), "uniform")
    free = int((~tiny.target_mask).sum())
    with pytest.raises(ValueError, match="n_rovers"):
        run_fleet(tiny, free + 1, "independent")
