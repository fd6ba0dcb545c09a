"""``run_fleet`` refuses bad inputs before any work, with one ValueError naming the argument."""
from __future__ import annotations

import pytest

from jaxplan import FabricParams, SpillParams
from jaxplan.fleet import FleetConfig, run_fleet
from jaxplan.transport.episode import EpisodeParams
from tests.fleet._sites import site

SCENE = site(0, (12, 12), "uniform")


@pytest.mark.parametrize("kwargs, field", [
    (dict(n_rovers=0), "FleetConfig.n_rovers"),
    (dict(n_rovers=65), "FleetConfig.n_rovers"),
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
    (dict(scene="site"), "scene"),
])
def test_bad_inputs_are_named(kwargs, field):
    args = dict(scene=SCENE, n_rovers=1, strategy="coordinated", params=None, spill=None, episode=None,
                max_steps=100)
    args.update(kwargs)
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        run_fleet(**args)


def test_more_rovers_than_free_cells_are_refused():
    tiny = site(0, (3, 3), "uniform")
    free = int((~tiny.target_mask).sum())
    with pytest.raises(ValueError, match="n_rovers"):
        run_fleet(tiny, free + 1, "independent")
