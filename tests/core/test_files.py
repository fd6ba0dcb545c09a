"""path_kind: what a user's path names, with the system's lookup errors turned into named ValueErrors;
read_text: a user's text file, bounded in size on request."""
from __future__ import annotations

import pytest

from jaxplan.core.files import path_kind, read_text, shown_path


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


def test_read_text_bounded(tmp_path):
    path = tmp_path / "cells.json"
    path.write_text("[[0, 0]]")
    assert read_text(path, "a list", max_bytes=8) == "[[0, 0]]"       # exactly the bound
    with pytest.raises(ValueError, match="is longer than 7 bytes, too long for a list"):
        read_text(path, "a list", max_bytes=7)
    assert read_text(path, "a list") == "[[0, 0]]"                     # no bound by default
    with pytest.raises(ValueError, match="longer than 16 bytes"):      # a device is read only up to the bound
        read_text("/dev/zero", "a list", max_bytes=16)
