"""Fuzzed CLI input files (tests/fuzz/fuzz_cli.py): valid scene files (.npz, .json), sweep specs (TOML) and
PushAround scenes (JSON), mutated (wrong types, NaN/inf, huge numbers, missing and extra keys, ragged rows,
truncation, bit flips, npz dtype/shape changes, zip corruption, ...), run through the CLI in-process.

Every case must either succeed (exit 0, a complete output, no temp files) or fail as bad input: exit
code 2, exactly one ``error:`` line naming the file, a flag or a field, and no ``--out`` path created.
Hypothesis draws the mutations (derandomized, so the suite always runs the same cases; no shrinking: a
case's description already says what was mutated). ``python -m tests.fuzz.fuzz_cli`` runs many more.
"""
from __future__ import annotations

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from tests.fuzz import fuzz_cli


def _fuzz(max_examples: int):
    return settings(max_examples=max_examples, deadline=None, derandomize=True, database=None,
                    phases=(Phase.explicit, Phase.generate),
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _check(kind: str, rng, tmp_path_factory) -> None:
    case = fuzz_cli.make_case(rng, tmp_path_factory.mktemp("fuzz") / "case", kind)
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
        assert case.input.is_file() and not case.out.exists() and case.kind in fuzz_cli.KINDS
        assert case.argv[0] == case.command and str(case.input) in case.argv
        assert case.describe().startswith(f"{case.kind} via {case.command}: ")
        kinds.add(case.kind)
        commands.add(case.command)
    assert kinds == set(fuzz_cli.KINDS) and commands == {"fabric", "episode", "sweep", "pusharound"}
