"""experiments/mjx_scale.py: the agreement counts and the tables (the MJX runs themselves are long)."""
import numpy as np
import pytest

from experiments.mjx_scale import Compiled, CompileOnly, agreement, markdown, markdown_rover
from jaxplan.pusharound.physics import build_push_world
from jaxplan.pusharound.push import make_push_simulator, simulate_pushes, stack_tasks
from tests.pusharound.test_physics import _scene, _task


def _outcome(poses, valid, hit):
    return {"poses": np.asarray(poses).tolist(), "valid": valid, "hit_fixed": hit}


def test_agreement_counts_verdicts_and_poses_beyond_tolerance():
    base = np.zeros((3, 2, 3))             # 3 candidates, 2 movables, (x, y, yaw)
    other = base.copy()
    other[1, 0, 0] = 0.02                  # 2 cm: beyond 1 cm
    other[2, 1, 2] = np.deg2rad(1.0)       # 1 degree: within 2
    other[0, 1, 2] = 2 * np.pi             # a full turn is no rotation
    ag = agreement(_outcome(other, [True, False, True], [False, False, True]),
                   _outcome(base, [True, True, True], [False, False, False]))
    assert (ag["valid_differ"], ag["hit_differ"], ag["pose_differ"], ag["n"]) == (1, 1, 1, 3)
    assert np.isclose(ag["max_dxy_m"], 0.02) and np.isclose(ag["max_dyaw_deg"], 1.0)
    assert np.isclose(ag["median_dxy_m"], 0.0)


def test_tables_list_every_row_and_comparison():
    ag = agreement(_outcome(np.zeros((2, 1, 3)), [True, True], [False, False]),
                   _outcome(np.zeros((2, 1, 3)), [True, True], [False, False]))
    mjx = {"movables": 1, "geoms": 4, "pairs": 3, "meshes": 1, "compile_s": 1.0, "warm_s": 2.0, "peak_gb": 0.5}
    rows = [{"scene": "nominal:0", "mjx": mjx, "c": {"warm_s": 0.1}, "agreement": ag, "agreement_no_sleep": ag,
             "c_sleep_vs_no_sleep": ag},
            {"scene": "nominal:1", "mjx": {"error": "timed out after 9 s"}}]
    text = markdown(rows, {"machine": "test", "batch": 2, "ticks": 80})
    assert "| nominal:0 | 1 | 4 | 3 | 1 | 1.0 | 2.00 | 0.50 |" in text
    assert "timed out after 9 s" in text
    assert "| nominal:0 | C vs C, sleeping off | 0 | 0 | 0 |" in text
    rover = markdown_rover([{"particles": 64, "geoms": 98, "max_geom_pairs": 256, "max_contact_points": 388,
                             "compile_s": 30.0, "program_gb": 0.25, "run_s": 5.0, "finite": 1.0, "peak_gb": 1.5},
                            {"particles": 256, "geoms": 290, "max_geom_pairs": 1024, "max_contact_points": 1540,
                             "compile_s": 40.0, "program_gb": None, "peak_gb": 2.0},
                            {"particles": 1024, "error": "timed out after 9 s"}],
                           {"machine": "test", "batch": 64, "rover_ticks": 20})
    assert "| 64 | 98 | 256 | 388 | 30.0 | 0.25 | 5.0 | 1.00 | 1.50 |" in rover
    assert "| 256 | 290 | 1024 | 1540 | 40.0 |  |  |  | 2.00 |" in rover and "| 1024 |" in rover


def test_compile_only_stops_the_caller_after_compiling():
    world = build_push_world(_scene())
    sim = make_push_simulator(world, "c")
    with pytest.raises(Compiled):
        simulate_pushes(world, stack_tasks([_task(world, (1, 0), (0.3, 0, 0))]), sim=CompileOnly(sim))
    assert sim.compile_seconds == 0.0 and sim.memory_bytes is None     # the C engine compiles nothing
