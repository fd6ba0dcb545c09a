"""Sweep spec files that are broken as files (binary, not UTF-8, empty, a folder) and scene files named
in a spec that are: one ValueError ``sweep spec: ...`` naming the file, one ``error:`` line in the CLI."""
from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxplan import sweep
from jaxplan.cli import main
from jaxplan.sweep.spec import Settings


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


def test_a_sweep_of_a_billion_settings_is_refused_before_anything_is_built():
    """The defect: three 1,000-value lists were accepted and grew by 200 MB/s writing nothing."""
    values = lambda lo, hi: [lo + (hi - lo) * i / 999 for i in range(1000)]  # noqa: E731
    spec = {"scenes": ["default"], "fabric": {"theta_tol_deg": values(10.0, 170.0), "tau_h": values(0.0, 1.0)},
            "spill": {"lam": values(0.01, 1.0)}}
    with pytest.raises(ValueError, match=r"1,000,000,000 settings \(1 scene\(s\) x 1000 theta_tol_deg"):
        sweep.load_spec(spec)


@settings(max_examples=60, deadline=None)
@given(n_scenes=st.integers(1, 3), lengths=st.lists(st.integers(1, 4), max_size=4), data=st.data())
def test_lazy_settings_list_what_the_product_lists(n_scenes, lengths, data):
    lists = [tuple(range(10 * j, 10 * j + n)) for j, n in enumerate(lengths)]
    k = data.draw(st.integers(0, len(lists)))
    lazy = Settings(n_scenes, lists[:k], lists[k:])
    want = [(i, c[:k], c[k:]) for i in range(n_scenes) for c in itertools.product(*lists)]
    assert len(lazy) == len(want) and list(lazy) == want
    assert lazy[-1] == want[-1] and lazy[1:3] == want[1:3]
    with pytest.raises(IndexError):
        lazy[len(want)]


def test_deeply_nested_toml_is_one_named_error(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text("scenes = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ValueError, match="nested too deeply"):
        sweep.load_spec(path)


def test_a_map_site_in_a_spec_is_placed_by_its_site_seed(tmp_path):
    from pathlib import Path

    import numpy as np

    from jaxplan.transport import site_from_map

    map_file = Path(__file__).resolve().parents[1] / "data" / "yard16.map"
    spec = sweep.load_spec({"scenes": [str(map_file)], "site_seed": 3})
    ((name, scene),) = spec.scenes
    want = site_from_map(map_file, 3)
    assert name == str(map_file) and bool(np.asarray(scene.blocked).any())
    np.testing.assert_array_equal(np.asarray(scene.obj), np.asarray(want.obj))
    with pytest.raises(ValueError, match=r"sweep spec: site_seed: expected an int in \[0, 2\^32\)"):
        sweep.load_spec({"scenes": [str(map_file)], "site_seed": -1})
    (tmp_path / "bad.map").write_text("type octile\nheight 1\nwidth 2\nmap\n.#\n")
    with pytest.raises(ValueError, match=r"sweep spec: scenes: Map file .*bad.map"):
        sweep.load_spec({"scenes": [str(tmp_path / "bad.map")]})
