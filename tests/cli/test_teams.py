"""``jaxplan teams``: writes Fig. 6 and summary.json for the paper scenario; bad input exits 2."""
from __future__ import annotations

import json

import pytest

from jaxplan.cli import main

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def teams_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("teams") / "out"
    code = main(["teams", "--out", str(out)])
    return code, out


def test_teams_writes_figure_and_summary(teams_run, capsys):
    code, out = teams_run
    assert code == 0
    png = out / "fig6.png"
    assert png.read_bytes()[:8] == PNG_MAGIC and png.stat().st_size > 10_000
    summary = json.loads((out / "summary.json").read_text())
    assert summary["strategy"] == "performance" and summary["deadline_s"] == 900.0
    assert [t["initial_mass_kg"] for t in summary["teams"]] == [12000.0, 8000.0]
    for team in summary["teams"]:
        assert 0 < team["delivered_kg"] <= team["initial_mass_kg"] + 1e-2
        assert team["clear_time_s"] <= team["finishing_time_s"]
        timeline = team["truck_count_timeline"]
        times = [t for t, _ in timeline]
        assert times[0] == 0.0 and times == sorted(times)
        assert max(n for _, n in timeline) == team["max_trucks"] <= 10
    assert summary["deadline_met"] == all(t["clear_time_s"] <= 900 for t in summary["teams"])
    assert sorted(p.name for p in out.iterdir()) == ["fig6.png", "run.json", "summary.json"]
    assert json.loads((out / "run.json").read_text())["files"] == ["fig6.png", "summary.json"]


def test_teams_options(tmp_path, capsys):
    out = tmp_path / "even"
    assert main(["teams", "--strategy", "even", "--v-after", "2", "--deadline", "1000",
                 "--seed", "3", "--steps", "1100", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["strategy"] == "even" and summary["deadline_s"] == 1000.0
    assert [t["truck_count_timeline"][0][1] for t in summary["teams"]] == [5, 5]
    assert "wrote" in capsys.readouterr().out


def test_teams_help_explains_options(capsys):
    with pytest.raises(SystemExit) as info:
        main(["teams", "--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    for option in ("--out", "--strategy", "--v-after", "--deadline", "--seed", "--steps"):
        assert option in text


@pytest.mark.parametrize("argv, field", [
    (["--v-after", "0"], "--v-after"),
    (["--deadline", "nan"], "--deadline"),
    (["--strategy", "greedy"], "--strategy"),
    (["--seed", "-1"], "--seed"),
    (["--steps", "0"], "--steps"),
])
def test_teams_bad_options_exit_2(argv, field, tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        main(["teams", "--out", str(tmp_path / "o"), *argv])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and field in err and "Traceback" not in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_teams_unwritable_out_exits_2(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(SystemExit) as info:
        main(["teams", "--out", str(blocker)])
    assert info.value.code == 2
    assert "--out" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["teams", "--out", str(blocker / "sub")])
    assert info.value.code == 2
    assert "--out" in capsys.readouterr().err
