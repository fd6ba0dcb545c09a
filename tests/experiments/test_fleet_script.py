"""The fleet benchmark script (experiments/fleet.py): bad walk caps are refused before any work. The
runs themselves are ``run_fleet``'s, tested in tests/fleet."""
import pytest

from experiments import fleet


@pytest.mark.parametrize("caps", [["0"], ["1024", "-3"], ["long"]])
def test_bad_walk_caps_exit_before_any_work(caps, capsys):
    with pytest.raises(SystemExit) as err:
        fleet.main(["--walk-cap", *caps])
    assert err.value.code == 2 and "--walk-cap" in capsys.readouterr().err
