"""Fuzzed CLI input files (tests/fuzz/fuzz_cli.py): valid scene files (.npz, .json), sweep specs (TOML) and
PushAround scenes (JSON), mutated (wrong types, NaN/inf, huge numbers, missing and extra keys, ragged rows,
truncation, bit flips, npz dtype/shape changes, zip corruption, ...), run through the CLI in-process; and
the other classes of case: archive members that declare or inflate to more than their bound, duplicated
and extra large members ("archive"), values inside thousands of lists or objects ("nesting"), and an
``--out`` folder prepared with links out of it, a foreign run.json, a held or a stale lock ("fs": no
file outside ``--out`` may change).

Every case must either succeed (exit 0, a complete output, no temp files) or fail as bad input: exit
code 2, exactly one ``error:`` line naming the file, a flag or a field, and no ``--out`` path created.
Hypothesis draws the mutations (derandomized, so the suite always runs the same cases; no shrinking: a
case's description already says what was mutated). ``python -m tests.fuzz.fuzz_cli`` runs many more.
"""
from __future__ import annotations

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from tests.fuzz import fuzz_cli


def _fuzz(max_examples: int):
    return settings(max_examples=max_examples, deadline=None, derandomize=True, database=None,
                    phases=(Phase.explicit, Phase.generate),
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _check(kind: str | None, rng, tmp_path_factory, cls: str = "inputs") -> None:
    case = fuzz_cli.make_case(rng, tmp_path_factory.mktemp("fuzz") / "case", kind, cls)
    with case.running():
        run = fuzz_cli.execute(case.argv)
    outcome, problems = fuzz_cli.check_case(case, run)
    assert outcome in fuzz_cli.PASSING, (
        f"{case.describe()}\nargv: {case.argv}\noutcome: {outcome}: {problems}\n"
        f"traceback: {run['exception']} (in {run['where']})\nstderr: {run['stderr'][-1500:]}")


@_fuzz(40)
@given(rng=st.randoms(use_true_random=False))
def test_mutated_npz_scene_is_read_or_rejected_cleanly(rng, tmp_path_factory):
    _check("scene.npz", rng, tmp_path_factory)


@_fuzz(40)
@given(rng=st.randoms(use_true_random=False))
def test_mutated_json_scene_is_read_or_rejected_cleanly(rng, tmp_path_factory):
    _check("scene.json", rng, tmp_path_factory)


@_fuzz(25)
@given(rng=st.randoms(use_true_random=False))
def test_mutated_sweep_spec_is_read_or_rejected_cleanly(rng, tmp_path_factory):
    _check("sweep.toml", rng, tmp_path_factory)


@_fuzz(15)
@given(rng=st.randoms(use_true_random=False))
def test_mutated_pusharound_scene_is_read_or_rejected_cleanly(rng, tmp_path_factory):
    _check("pusharound.json", rng, tmp_path_factory)


@_fuzz(10)
@given(rng=st.randoms(use_true_random=False))
def test_archive_members_over_their_bounds_are_rejected_cleanly(rng, tmp_path_factory):
    _check("scene.npz", rng, tmp_path_factory, "archive")


@_fuzz(9)
@given(rng=st.randoms(use_true_random=False))
def test_deeply_nested_documents_are_rejected_cleanly(rng, tmp_path_factory):
    _check(None, rng, tmp_path_factory, "nesting")


@_fuzz(10)
@given(rng=st.randoms(use_true_random=False))
def test_prepared_out_folders_leave_files_outside_alone(rng, tmp_path_factory):
    _check("scene.npz", rng, tmp_path_factory, "fs")


def test_each_way_of_preparing_out_is_run_and_checked(tmp_path):
    """Each fs mode once, with a valid scene: links out of --out and stale locks run through (the victim
    outside is left alone), a foreign run.json and a held lock are refused with one error line."""
    import random

    seen = {}
    for seed in range(200):
        case = fuzz_cli.make_case(random.Random(seed), tmp_path / str(seed), "scene.npz", "fs")
        if case.fs in seen or len(case.mutations) != 1:   # one mode each, the input unmutated
            continue
        with case.running():
            run = fuzz_cli.execute(case.argv)
        seen[case.fs] = (run["code"], fuzz_cli.check_case(case, run), run["stderr"][-500:])
        if len(seen) == len(fuzz_cli.FS_MODES):
            break
    assert set(seen) == set(fuzz_cli.FS_MODES)
    for mode, (code, outcome, stderr) in seen.items():
        assert outcome[0] in fuzz_cli.PASSING, (mode, outcome, stderr)
        assert code == (2 if mode in ("busy", "foreign run.json") else 0), (mode, code, stderr)
    assert "is in use by another run" in seen["busy"][2]


def test_a_changed_file_outside_out_is_a_finding(tmp_path):
    """The harness: a victim changed or removed counts as touched_outside, whatever the exit code."""
    import random

    case = fuzz_cli.make_case(random.Random(1), tmp_path / "a", "scene.json", "fs")
    victim = next(iter(case.victims))
    victim.write_text("changed")
    assert fuzz_cli.check_case(case, {"code": 2, "exception": None, "stderr": "error: x"})[0] == "touched_outside"
    victim.unlink()
    assert fuzz_cli.check_case(case, {"code": 0, "exception": None, "stderr": ""})[0] == "touched_outside"


def test_nesting_is_as_deep_as_it_says(tmp_path):
    """The nesting mutation writes thousands of levels, in JSON and in TOML."""
    import random
    import tomllib

    for kind in ("scene.json", "pusharound.json", "sweep.toml"):
        case = fuzz_cli.make_case(random.Random(3), tmp_path / kind, kind, "nesting")
        text = case.input.read_text()
        depth = max(text.count("["), text.count("{"))
        assert depth >= min(fuzz_cli.NEST_DEPTHS), (kind, case.mutations)
        if kind == "sweep.toml":
            with pytest.raises(RecursionError):
                tomllib.loads(text)


def test_an_unmutated_case_of_each_kind_passes(tmp_path):
    """The harness itself: the valid inputs it starts from run through and pass every check."""
    import random

    for kind in fuzz_cli.KINDS:
        rng = random.Random(0)
        rng.random = lambda: 0.01   # below every mutation threshold: the file stays valid
        case = fuzz_cli.make_case(rng, tmp_path / kind, kind)
        assert case.mutations == []
        run = fuzz_cli.execute(case.argv)
        assert fuzz_cli.check_case(case, run) == ("exit0", []), (kind, run["stderr"][-1500:])


def test_every_case_is_made_and_described(tmp_path):
    """The mutators never fail themselves, and each case names its command and mutations."""
    kinds, commands = set(), set()
    for index in range(150):
        case = fuzz_cli.build_case(7, index, tmp_path / str(index))
        assert case.input.is_file() and case.kind in fuzz_cli.CLASS_KINDS[case.cls]
        assert case.out.exists() == (case.cls == "fs")   # only an fs case prepares --out before the run
        assert case.argv[0] == case.command and str(case.input) in case.argv
        assert case.describe().startswith(f"{case.kind} via {case.command}: ")
        kinds.add(case.kind)
        commands.add(case.command)
    assert kinds == set(fuzz_cli.KINDS) and commands == {"fabric", "episode", "sweep", "pusharound"}
