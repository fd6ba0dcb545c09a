"""Every flag of every subcommand is checked as it is parsed: NaN, inf, zero, negative, huge and unknown
values give one ``error: --flag: ...`` line naming the allowed range, exit code 2, before any work and
before anything is written (``jaxplan.cli.common.ranged`` and ``Parser``)."""
from __future__ import annotations

import pytest

from jaxplan.cli import main
from jaxplan.transport import fabric as fabric_mod

# the required arguments of each command; the bad flag is appended
BASE = {
    "fabric": ["fabric", "--scene", "default", "--out", "f.npz"],
    "demo": ["demo", "--out", "d"],
    "episode": ["episode", "--scene", "default", "--out", "e"],
    "rover": ["rover", "--out", "r"],
    "pusharound": ["pusharound", "--out", "p"],
    "teams": ["teams", "--out", "t"],
    "sweep": ["sweep", "s.toml", "--out", "s.csv"],
}

TRANSPORT = [
    ("fabric", "--k", ["0", "-1", "25", "1000", "4.5", "x"]),
    ("fabric", "--theta-tol", ["nan", "inf", "-inf", "0", "180", "-5", "abc"]),
    ("fabric", "--tau-h", ["nan", "inf", "-1", "1.5"]),
    ("demo", "--fps", ["0", "-2", "51", "1e9", "2.5"]),
    ("episode", "--fps", ["0", "-2"]),
    ("episode", "--lam", ["nan", "inf", "-1"]),
    ("episode", "--spill-threshold", ["nan", "inf", "-0.1"]),
    ("episode", "--capacity", ["0", "nan", "inf", "-3"]),
    ("episode", "--mu", ["nan", "inf", "-1"]),
    ("episode", "--miss", ["nan", "-1"]),
    ("episode", "--turn-saturation", ["0", "nan", "-inf"]),
    ("episode", "--max-pushes", ["-1", "1000001", str(10 ** 30), "nan"]),
    ("episode", "--rearrange-margin", ["nan", "-2", "-inf"]),
    ("episode", "--stop-fraction", ["nan", "1", "1.5", "-0.1", "inf"]),
    ("episode", "--source-rule", ["biggest"]),
    ("episode", "--rebuild", ["never"]),
    ("demo", "--theta-tol", ["nan", "200"]),
]
OTHERS = [
    ("rover", "--routes", ["0", "65", "-1"]),
    ("rover", "--speed", ["0", "inf", "nan", "3", "0.01", "-1"]),
    ("rover", "--friction", ["0", "nan", "inf", "100"]),
    ("rover", "--backend", ["gpu"]),
    ("rover", "--solver", ["PGS"]),
    ("rover", "--lam", ["inf"]),
    ("pusharound", "--fps", ["0", "-1"]),
    ("pusharound", "--seed", ["-1", str(2 ** 32), "1.5"]),
    ("pusharound", "--time-limit", ["0", "inf", "nan", "-5", "1e9"]),
    ("pusharound", "--max-replans", ["-1", "101", str(10 ** 20)]),
    ("pusharound", "--max-frames", ["1", "0", "10001"]),
    ("pusharound", "--backend", ["cuda"]),
    ("teams", "--strategy", ["greedy", ""]),
    ("teams", "--v-after", ["0", "inf", "nan", "-1", "1e9"]),
    ("teams", "--deadline", ["nan", "inf", "0", "-900", "1e9"]),
    ("teams", "--seed", ["-1", str(2 ** 40)]),
    ("teams", "--steps", ["0", "-5", "1000000000"]),
    ("sweep", "--memory-budget-mb", ["0", "nan", "inf", "-1", "1e12"]),
    ("sweep", "--backend", ["spark"]),
]
CASES = [(cmd, flag, value) for cmd, flag, values in TRANSPORT + OTHERS for value in values]


def _one_error_line(argv, capsys) -> str:
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("cmd, flag, value", CASES, ids=[f"{c}{f}={v[:12]}" for c, f, v in CASES])
def test_bad_flag_value_is_one_error_line_naming_the_flag(cmd, flag, value, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    line = _one_error_line(BASE[cmd] + [f"{flag}={value}"], capsys)
    assert line.startswith(f"error: {flag}: "), line
    assert f"jaxplan {cmd} --help" in line
    assert list(tmp_path.iterdir()) == []   # nothing created


@pytest.mark.parametrize("cmd, flag, value, words", [
    ("demo", "--fps", "0", "an int in [1, 50]"),
    ("fabric", "--k", "1000", "an int in [1, 24]"),
    ("fabric", "--theta-tol", "nan", "a number in (0, 180) degrees"),
    ("episode", "--rearrange-margin", "nan", ">= 0 (inf allowed)"),
    ("episode", "--stop-fraction", "1", "in [0, 1)"),
    ("pusharound", "--seed", "-1", "an int in [0, 4294967295]"),
    ("teams", "--strategy", "greedy", "'performance', 'even', 'largest', 'oracle'"),
])
def test_the_error_states_the_allowed_range(cmd, flag, value, words, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    line = _one_error_line(BASE[cmd] + [flag, value], capsys)
    assert words in line, line
    assert f"got {value};" in line or "invalid choice" in line, line


def test_good_extremes_parse(tmp_path):
    from jaxplan.cli.app import build_parser

    args = build_parser().parse_args(["episode", "--scene", "default", "--out", "e", "--rearrange-margin", "inf",
                                      "--turn-saturation", "inf", "--fps", "50", "--max-pushes", "0",
                                      "--stop-fraction", "0"])
    assert args.rearrange_margin == float("inf") and args.fps == 50 and args.max_pushes == 0
    args = build_parser().parse_args(["fabric", "--scene", "default", "--out", "f.npz", "--k", "24"])
    assert args.k == 24


@pytest.mark.parametrize("argv, starts", [
    (["fabric", "--out", "x.npz"], "error: the following arguments are required: --scene"),
    (["nosuchcommand"], "error: COMMAND: invalid choice: 'nosuchcommand'"),
    (["demo", "--fps"], "error: --fps: expected one argument"),
    (["teams", "--bogus", "1"], "error: unrecognized arguments: --bogus 1"),
    ([], "error: the following arguments are required: COMMAND"),
])
def test_argparse_usage_errors_are_one_line(argv, starts, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    line = _one_error_line(argv, capsys)
    assert line.startswith(starts), line
    assert "usage:" not in line


def test_k_refused_when_its_estimated_memory_does_not_fit(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(fabric_mod, "available_memory_bytes", lambda: 5 * 10 ** 9)
    line = _one_error_line(["fabric", "--scene", "default", "--k", "16", "--out", "sub/k16.npz"], capsys)
    assert line.startswith("error: --k: K = 16 needs about 7.0 GB") and "25x25" in line, line
    assert "5.0 GB of memory available" in line and "use k <= 14" in line, line
    assert list(tmp_path.iterdir()) == []


def test_episode_on_a_grid_too_large_for_memory_names_the_scene(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(fabric_mod, "available_memory_bytes", lambda: 10 ** 6)
    line = _one_error_line(["episode", "--scene", "default", "--out", "e"], capsys)
    assert line.startswith("error: --scene: K = 4 needs about") and "1 MB of memory available" in line, line
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [
    ["demo", "--out", "blocker/sub"],
    ["demo", "--out", "blocker"],
    ["fabric", "--scene", "default", "--out", "blocker/f.npz"],
    ["teams", "--out", "blocker"],
    ["sweep", "s.toml", "--out", "blocker/s.csv"],
    ["sweep", "s.toml", "--out", "."],
])
def test_unusable_out_is_refused_before_any_work(argv, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "blocker").write_text("a file")

    def no_work(*args, **kwargs):
        raise AssertionError("work started")

    monkeypatch.setattr(fabric_mod, "build_fabric", no_work)
    monkeypatch.setattr("jaxplan.teams.report.run_paper", no_work)
    line = _one_error_line(argv, capsys)
    assert line.startswith("error: --out: "), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker"]


def test_sweep_address_needs_the_ray_backend(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    line = _one_error_line(["sweep", "s.toml", "--out", "s.csv", "--address", "10.0.0.5:6379"], capsys)
    assert line.startswith("error: --address: ") and "--backend ray" in line


def test_a_large_k_that_fits_gets_a_warning_line(monkeypatch, capsys):
    from argparse import Namespace

    from jaxplan import FabricParams, builtin_scene
    from jaxplan.cli.common import check_fabric_memory

    monkeypatch.setattr(fabric_mod, "available_memory_bytes", lambda: 100 * 10 ** 9)
    check_fabric_memory(Namespace(k=12), builtin_scene("default"), FabricParams(k=12))
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("warning: --k: K = 12 needs about 1.") and "minutes" in err[0]
    check_fabric_memory(Namespace(k=4), builtin_scene("default"), FabricParams(k=4))
    assert capsys.readouterr().err == ""
