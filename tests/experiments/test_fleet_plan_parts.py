"""The planning-breakdown script (experiments/fleet_plan_parts.py): its table renders every part and
bad arguments are refused before any work. A real run warms a fleet up for minutes; the parts it
times are tested in tests/fleet."""
import pytest

from experiments import fleet_plan_parts

PARTS = ("choose_sources", "path_screen", "plan_candidates", "plan_two_new", "assign_planned", "step_planning",
         "step_fresh_candidates", "plan_whole_cap")


def _result(lengths=(120.0, 431)):
    ms = {part: float(k + 1) for k, part in enumerate(PARTS)} | {"full_build": 100.0}
    return dict(site="site512", n_rovers=64, warmup=400, idle=24, chosen=22, screened_out=12, newly_planned=10,
                ms=ms, route_slots=8194, core_rows=74258, route_cells_median=lengths[0],
                route_cells_max=lengths[1], short_cap=128, walk_cap=4096, same_tasks_whole_cap=True)


def test_the_table_has_every_part_and_its_share_of_a_build():
    text = fleet_plan_parts.markdown(_result(), "meta")
    assert "| screen their paths (22 chosen, 12 set aside) | 2.00 | 0.020 |" in text
    assert "| plan the others (10 new tasks) | 3.00 | 0.030 |" in text
    assert "| full build of the fabric | 100.00 | 1.000 |" in text
    assert "| plan the same at the whole walk cap only (4096; the default tries 128 first) | 8.00 | 0.080 |" in text
    assert "both ways planned the same tasks" in text
    assert "DIFFERENT tasks" in fleet_plan_parts.markdown(_result() | {"same_tasks_whole_cap": False}, "meta")
    assert "Per task planned beyond two: -0.12 ms" in text and "routes of median 120, max 431 cells" in text
    assert "routes of - cells" in fleet_plan_parts.markdown(_result((None, None)), "meta")
    assert "beyond two: -." in fleet_plan_parts.markdown(_result() | {"newly_planned": 2}, "meta")


@pytest.mark.parametrize("argv", [["--rovers", "0"], ["--rovers", "5000"], ["--warmup", "0"], ["--site", "site64"]])
def test_bad_arguments_exit_before_any_work(argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as err:
        fleet_plan_parts.main([*argv, "--results-dir", str(tmp_path / "out")])
    assert err.value.code == 2 and "error:" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
