"""``jaxplan rover``: writes the table, figure and summary for a small scene; bad input exits 2."""
from __future__ import annotations

import json

import numpy as np
import pytest

from jaxplan.cli import main
from jaxplan.transport.scene import Scene, box


def _tiny_file(tmp_path):
    obj = np.zeros((5, 8))
    obj[2, 1:4] = [2, 1, 2]
    path = tmp_path / "tiny.json"
    Scene.from_arrays(obj, box(6.0, 0.0, 8.0, 5.0), name="tiny").save(path)
    return path


def test_rover_writes_summary_table_and_figure(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["rover", "--scene", str(_tiny_file(tmp_path)), "--routes", "1", "--backend", "c",
                 "--friction", "0.8", "--capacity", "3", "--mu", "0.02", "--no-render", "--solver", "Newton",
                 "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["friction"] == 0.8 and summary["solver"] == "Newton"
    # --capacity / --mu select the capacity-aware 2D model for the prediction: 5 objects collected,
    # a 3-object blade (soft limit, temperature 0.5) delivers about 3 of them
    assert summary["spill"]["model"] == "CapacitySpillParams" and summary["spill"]["capacity"] == 3.0
    # the turning terms stay off unless asked for; JSON has no infinity, so the saturation is "inf"
    assert summary["spill"]["miss"] == 0.0 and summary["spill"]["turn_saturation"] == "inf"
    assert 2.0 < summary["routes"][0]["predicted_delivered"] < 3.5
    (route,) = summary["routes"]
    for key in ("predicted_delivered", "delivered", "mean_lateral", "max_lateral", "finite", "collected"):
        assert key in route
    assert route["finite"] is True and route["collected"] == 5.0
    assert route["delivered"] + route["spilled"] + route["left_behind"] + route["lost"] == route["collected"]
    assert summary["frames"] == "skipped (--no-render)"
    assert (out / "rover.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| route |" in (out / "routes.md").read_text()
    assert "wrote" in capsys.readouterr().out


@pytest.mark.parametrize("argv, field", [(["--routes", "0"], "--routes"), (["--speed", "-1"], "--speed"),
                                         (["--scene", "nope.json"], "--scene"), (["--lam", "-1"], "lam"),
                                         (["--friction", "0"], "--friction"), (["--capacity", "0"], "--capacity"),
                                         (["--mu", "-1"], "--mu"), (["--mu", "nan"], "--mu"),
                                         (["--miss", "-0.1"], "--miss"),
                                         (["--turn-saturation", "0"], "--turn-saturation"),
                                         (["--turn-saturation", "nan"], "--turn-saturation")])
def test_rover_bad_input_exits_2(tmp_path, capsys, argv, field):
    with pytest.raises(SystemExit) as info:
        main(["rover", "--out", str(tmp_path / "o"), *argv])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and field in err[0]


def test_turning_options_select_the_capacity_model():
    from jaxplan.cli.app import build_parser
    from jaxplan.cli.transport import spill_params

    args = build_parser().parse_args(["rover", "--miss", "0.2", "--turn-saturation", "1.5"])
    spill = spill_params(args)
    assert type(spill).__name__ == "CapacitySpillParams"
    assert float(spill.miss) == 0.2 and float(spill.turn_saturation) == 1.5 and float(spill.mu) == 0.0


def test_rover_predicts_with_the_fitted_model_unless_a_spill_option_is_given():
    from jaxplan.cli.app import build_parser
    from jaxplan.cli.transport import SPILL_MODEL_NAMES, rover_spill_models, spill_dict, spill_params
    from jaxplan.transport.spillage import LEARNED_FIT, SpillParams
    from jaxplan.transport.spillage.capacity import ROVER_FIT

    parse = build_parser().parse_args
    # the learned model by default, the capacity fit on request; both go into summary.json
    assert tuple(rover_spill_models()) == SPILL_MODEL_NAMES
    assert rover_spill_models()[parse(["rover"]).spill_model] is LEARNED_FIT
    assert rover_spill_models()[parse(["rover", "--spill-model", "rover-fit"]).spill_model] is ROVER_FIT
    learned = json.loads(json.dumps(spill_dict(LEARNED_FIT)))
    assert learned["model"] == "LearnedSpillParams" and np.shape(learned["w1"]) == np.shape(LEARNED_FIT.w1)
    assert spill_params(parse(["rover"]), default=ROVER_FIT) is ROVER_FIT
    assert spill_params(parse(["rover", "--lam", "0.05"]), default=ROVER_FIT) == SpillParams(lam=0.05)
    assert spill_params(parse(["rover", "--spill-threshold", "0.01"]), default=ROVER_FIT) != ROVER_FIT
    # planning commands keep the paper's curvature model by default
    assert spill_params(parse(["episode", "--scene", "default", "--out", "x"])) == SpillParams(lam=0.05)
