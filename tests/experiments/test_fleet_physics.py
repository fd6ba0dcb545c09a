"""The concurrent-push physics script (experiments/fleet_physics.py): its tables render every field (a
non-finite number arrives as None in the strict JSON) and bad arguments are refused before any work.
The physics itself is tested in tests/fleet/test_physics.py; a real run takes tens of seconds."""
import pytest

from experiments import fleet_physics


def _result():
    route = {"route": 0, "source": [3, 4], "n_cells": 5, "fallback": True, "collected": 6.0, "delivered": 5.0,
             "left_behind": 0.0, "spilled": 1.0, "lost": 0.0, "predicted_delivered": 5.5, "relative_error": 0.09,
             "within": True, "alone_delivered": 6.0, "alone_within": True, "finish_time": None}
    summary = {"contacts": 3, "contact_pairs": [[0, 1]], "swept_overlaps": [[0, 1]], "min_axle_distance_cells": None,
               "fraction_within": 1.0, "alone_fraction_within": 1.0, "all_reached": False, "together_s": 4.0}
    return {"date": "d", "host": "h", "rovers": 1, "candidates": 10, "total_s": 5.0, "skipped": ["piles16_s1"],
            "scenes": [{"scene": "piles16_s0", "target_cells": 7, "summary": summary, "routes": [route]}],
            "totals": {"contacts": 3, "pushes": 1, "within": 1, "alone_within": 1, "fraction_within": 1.0}}


def test_the_tables_render_missing_numbers_as_dashes():
    text = fleet_physics.markdown(_result())
    assert "| piles16_s0 | 7 | 3 | [[0, 1]] | [[0, 1]] | - | 1.00 | 1.00 | False | 4 |" in text
    assert "| piles16_s0 | 0 | (3, 4) | 5 | True | 6 | 5.5 | 5 | 0.09 | True | 6 | True | 1 | 0 | - |" in text
    assert "Skipped (fewer than 1 disjoint routes): ['piles16_s1']" in text


@pytest.mark.parametrize("argv", [["--rovers", "0"], ["--candidates", "2", "--rovers", "4"], ["--size", "4"],
                                  ["--sites", "nowhere"]])
def test_bad_arguments_exit_before_any_work(argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as err:
        fleet_physics.main([*argv, "--results-dir", str(tmp_path / "out")])
    assert err.value.code == 2 and "error:" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
