"""path_kind: what a user's path names, with the system's lookup errors turned into named ValueErrors."""
from __future__ import annotations

import pytest

from jaxplan.core.files import path_kind, shown_path


def test_kinds(tmp_path):
    (tmp_path / "f").write_text("x")
    assert path_kind(tmp_path / "f") == "file"
    assert path_kind(tmp_path) == "dir"
    assert path_kind(tmp_path / "missing") == "missing"
    assert path_kind(tmp_path / "f" / "below_a_file") == "missing"
    assert path_kind("/dev/null") == "other"


@pytest.mark.parametrize("bad", ["x" * 300, "a\0b"])
def test_unusable_paths_are_named_value_errors(bad):
    with pytest.raises(ValueError, match="is not a usable path") as info:
        path_kind(bad)
    assert len(str(info.value)) < 200   # a long name is shortened in the message


def test_shown_path_keeps_both_ends():
    text = shown_path("/very/" + "x" * 200 + "/scene.npz")
    assert text.startswith("'/very/") and text.endswith("scene.npz'") and "..." in text
    assert shown_path("short.npz") == "'short.npz'"
