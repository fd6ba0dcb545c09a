"""The update-overheads benchmark (experiments/update_overheads.py) on a tiny grid."""
from experiments import update_overheads


def test_the_one_program_peer_gives_the_library_fabric_and_both_are_timed():
    # programs_ab stops with an error where the peer's fabric differs from selective_rebuild's
    result = update_overheads.programs_ab(12, ticks=2, repeats=1)
    assert result["pushes"] == 4
    assert all(ms > 0 for ms in result["median_ms"].values())
    assert len(result["median_ms"]) == 3 and all(r > 0 for r in result["ratio_to_two"].values())
    assert result["peer_first_call_s"] > 0

