"""The spill data generator (experiments/spill_data.py): a quick run writes an archive whose records
conserve mass, stay on the grid and split by scene, and a manifest that counts them; the scene
families are deterministic; bad arguments stop before any work."""
import json

import numpy as np
import pytest

from experiments import spill_data


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("spill") / "quick"
    manifest = spill_data.main(["--quick", "--out", str(out)])
    return manifest, dict(np.load(out.with_suffix(".npz"))), json.loads(out.with_suffix(".json").read_text()), out


def test_a_quick_run_writes_records_that_conserve_mass(quick):
    manifest, data, written, out = quick
    assert manifest == written
    assert sorted(p.name for p in out.parent.iterdir()) == ["quick.json", "quick.npz"]     # no partial file
    n = data["delivered"].shape[0]
    assert n == written["counts"]["train"]["records"] + written["counts"]["heldout"]["records"] > 0
    # the particles rasterised back to the grid, with what left the world, are the counts before
    before, after = data["obj_before"].sum((1, 2)), data["obj_after"].sum((1, 2))
    np.testing.assert_allclose(after + data["lost"], before, rtol=1e-5)
    assert np.all(data["finite"]) and np.all(data["collected"] >= data["delivered"] - 1e-4)
    cells = data["cells"]
    valid = np.arange(cells.shape[1])[None] < data["n_cells"][:, None]
    assert np.all((cells[valid] >= 0) & (cells[valid] < np.asarray(spill_data.SHAPE)))
    assert np.all(cells[~valid] == -1)


def test_records_split_by_scene(quick):
    _, data, written, _ = quick
    heldout = data["scene_heldout"][data["scene"]]
    assert heldout.any() and (~heldout).any()
    assert written["counts"]["heldout"]["records"] == int(heldout.sum())
    assert list(data["scene_family"]) == list(spill_data.FAMILIES)


def test_scene_families_are_deterministic():
    for family in spill_data.FAMILIES:
        a, b = spill_data.family_scene(family, 0.35, 3), spill_data.family_scene(family, 0.35, 3)
        np.testing.assert_array_equal(np.asarray(a.obj), np.asarray(b.obj))
        assert float(np.asarray(a.obj).sum()) > 0 and not np.asarray(a.obj)[np.asarray(a.target_mask)].any()


@pytest.mark.parametrize("argv", [["--layouts", "0"], ["--seeds", "-1"]])
def test_bad_arguments_exit_before_any_work(argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as err:
        spill_data.main([*argv, "--out", str(tmp_path / "x")])
    assert err.value.code == 2 and "error:" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
