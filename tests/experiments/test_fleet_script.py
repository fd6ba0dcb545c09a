"""The fleet benchmark script (experiments/fleet.py): bad walk lengths are refused before any work. The
runs themselves are ``run_fleet``'s, tested in tests/fleet."""
import pytest

from experiments import fleet


@pytest.mark.parametrize("flag", ["--walk-cap", "--short-cap"])
@pytest.mark.parametrize("caps", [["0"], ["1024", "-3"], ["long"]])
def test_bad_walk_lengths_exit_before_any_work(flag, caps, capsys):
    with pytest.raises(SystemExit) as err:
        fleet.main([flag, *caps])
    assert err.value.code == 2 and flag in capsys.readouterr().err
