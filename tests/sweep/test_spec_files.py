"""Sweep spec files that are broken as files (binary, not UTF-8, empty, a folder) and scene files named
in a spec that are: one ValueError ``sweep spec: ...`` naming the file, one ``error:`` line in the CLI."""
from __future__ import annotations

import pytest

from jaxplan import sweep
from jaxplan.cli import main


@pytest.mark.parametrize("content, words", [
    (bytes(range(256)), "is not UTF-8 text"),
    ('scenes = ["café"]'.encode("latin-1"), "is not UTF-8 text"),
    (b"", "is empty"),
    (b"  \n\n", "is empty"),
    (b"scenes = [", "not valid TOML"),
])
def test_broken_spec_file(tmp_path, content, words):
    path = tmp_path / "spec.toml"
    path.write_bytes(content)
    with pytest.raises(ValueError) as err:
        sweep.load_spec(path)
    assert str(err.value).startswith(f"sweep spec: {path}: ") and words in str(err.value)


def test_spec_path_is_a_directory_or_missing(tmp_path):
    with pytest.raises(ValueError, match=r"^sweep spec: .*: is a directory"):
        sweep.load_spec(tmp_path)
    with pytest.raises(ValueError, match=r"^sweep spec: .*missing.toml: no such file"):
        sweep.load_spec(tmp_path / "missing.toml")


@pytest.mark.parametrize("name, content, words", [
    ("trunc.npz", b"PK\x03\x04 truncated", "damaged"),
    ("noise.json", bytes(range(256)), "is not UTF-8 text"),
    ("folder.npz", None, "is a directory"),
])
def test_broken_scene_file_named_in_a_spec(tmp_path, name, content, words):
    if content is None:
        (tmp_path / name).mkdir()
    else:
        (tmp_path / name).write_bytes(content)
    with pytest.raises(ValueError) as err:
        sweep.load_spec({"scenes": [str(tmp_path / name)]})
    message = str(err.value)
    assert message.startswith("sweep spec: scenes: ") and name in message and words in message


def test_cli_broken_spec_is_one_error_line(tmp_path, capsys):
    spec = tmp_path / "spec.toml"
    spec.write_bytes(bytes(range(256)))
    out = tmp_path / "out.csv"
    with pytest.raises(SystemExit) as info:
        main(["sweep", str(spec), "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: sweep spec: {spec}: is not UTF-8 text"), err
    assert not out.exists()


@pytest.mark.parametrize("spec, words", [
    ({"random_scenes": {"seeds": [0], "shape": [2**64, 5]}},
     "random_scenes.shape: expected [H, W] with ints in [3, 4096]"),
    ({"scenes": ["x" * 300]}, "scenes: 'xxx"),
    ({"scenes": ["default"], "spill": {"lam": [0.0, 10**400]}}, "spill.lam: expected a finite number"),
])
def test_absurd_sizes_and_names_are_named(spec, words):
    with pytest.raises(ValueError) as info:
        sweep.load_spec(spec)
    assert str(info.value).startswith("sweep spec: ") and words in str(info.value), str(info.value)
