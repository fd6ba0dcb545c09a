"""Parameter sweeps (jaxplan.sweep): spec validation, vmapped chunks equal single builds, resumption."""
from __future__ import annotations

import numpy as np
import pytest

from jaxplan import sweep
from jaxplan.cli import main
from jaxplan.transport.params import FabricParams
from tests._scenes import reference_of

# Two random 7x7 scenes x 2 angles x 2 thresholds x 2 spill lambdas = 16 settings in chunks of 4.
SPEC = {"random_scenes": {"seeds": [3, 4], "shape": [7, 7], "density": 0.6},
        "fabric": {"theta_tol_deg": [45.0, 60.0], "tau_h": [0.3, 0.5]},
        "spill": {"lam": [0.0, 0.1]},
        "metrics": {"top_sources": 3}}
TOML = """
[random_scenes]
seeds = [3, 4]
shape = [7, 7]
density = 0.6
[fabric]
theta_tol_deg = [45.0, 60.0]
tau_h = [0.3, 0.5]
[spill]
lam = [0.0, 0.1]
[metrics]
top_sources = 3
"""


@pytest.fixture(scope="module")
def budget():
    """Room for one table (theta x scene) and its 4 settings (tau_h x lam) per chunk: 4 chunks."""
    return sweep.bytes_per_table(sweep.load_spec(SPEC).scenes[0][1], per_table=4) / 2**20


@pytest.fixture(scope="module")
def full_run(tmp_path_factory, budget):
    out = tmp_path_factory.mktemp("sweep") / "full.csv"
    sweep.run_sweep(SPEC, out, memory_budget_mb=budget, progress=False)
    return out.read_text()


def _rows(text):
    lines = text.splitlines()
    return lines[0].split(","), [line.split(",") for line in lines[1:]]


def test_one_row_per_setting_in_sweep_order(full_run):
    header, rows = _rows(full_run)
    assert header == sweep.columns_of(sweep.load_spec(SPEC))
    assert [int(r[0]) for r in rows] == list(range(16))
    assert [r[1] for r in rows[:8]] == ["random:3"] * 8 and [r[4] for r in rows[:2]] == ["0.0", "0.1"]
    col = {name: i for i, name in enumerate(header)}
    for r in rows:   # spill only ever loses mass; without it the selected routes deliver what they collect
        delivered, collected = float(r[col["top_delivered"]]), float(r[col["top_collected"]])
        assert delivered <= collected + 1e-4 and np.isfinite(delivered)
        if r[col["spill_lam"]] == "0.0":
            assert delivered == pytest.approx(collected, abs=1e-4)


def test_vmapped_rows_equal_the_serial_reference(full_run):
    header, rows = _rows(full_run)
    col = {name: i for i, name in enumerate(header)}
    spec = sweep.load_spec(SPEC)
    for r in rows[::3]:
        scene = dict(spec.scenes)[r[col["scene"]]]
        params = FabricParams(theta_tol_deg=float(r[col["theta_tol_deg"]]), tau_h=float(r[col["tau_h"]]))
        ref = reference_of(scene, params, with_connectors=False)
        occ = ref.occupied
        assert int(r[col["occupied_cells"]]) == occ.sum()
        assert float(r[col["mean_value"]]) == pytest.approx(ref.value[occ].mean(), rel=1e-5)
        assert float(r[col["mean_length"]]) == pytest.approx(ref.length[occ].mean(), rel=1e-5)
        assert int(r[col["highway_cells"]]) == int(ref.highways.sum())
        assert float(r[col["max_heat"]]) == pytest.approx(ref.heat.max(), rel=1e-5)
        if r[col["spill_lam"]] == "0.0":
            top = np.sort(ref.value[occ])[::-1][:3].sum()
            assert float(r[col["top_collected"]]) == pytest.approx(top, rel=1e-5)


class _Stop(Exception):
    pass


def test_interrupted_sweep_resumes_to_the_same_file(tmp_path, full_run, budget):
    out = tmp_path / "resumed.csv"

    def stop_after_two(done, total):
        if done >= 8:
            raise _Stop

    with pytest.raises(_Stop):
        sweep.run_sweep(SPEC, out, memory_budget_mb=budget, progress=False, on_chunk=stop_after_two)
    partial = out.read_text()
    assert len(partial.splitlines()) == 1 + 8
    with open(out, "a") as fh:   # a row torn by the kill, mid-write
        fh.write("8,random:4,45.0,0.3,0.0,2")
    sweep.run_sweep(SPEC, out, memory_budget_mb=budget, progress=False)
    assert out.read_text() == full_run
    sweep.run_sweep(SPEC, out, memory_budget_mb=budget, progress=False)   # nothing left to do
    assert out.read_text() == full_run


_KILLABLE = """
import sys, time
from jaxplan import sweep
spec, out, budget = eval(sys.argv[1]), sys.argv[2], float(sys.argv[3])
sweep.run_sweep(spec, out, memory_budget_mb=budget, progress=False, on_chunk=lambda done, total: time.sleep(60))
"""


def test_sweep_killed_by_sigkill_resumes_to_the_same_file(tmp_path, full_run, budget):
    # a real kill -9 of a separate process after its first chunk is on disk: no handler runs
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "killed.csv"
    proc = subprocess.Popen([sys.executable, "-c", _KILLABLE, repr(SPEC), str(out), str(budget)],
                            env=dict(os.environ, JAX_PLATFORMS="cpu"))
    try:
        deadline = time.monotonic() + 240
        while not (out.exists() and len(out.read_text().splitlines()) > 1):
            assert proc.poll() is None and time.monotonic() < deadline, "the sweep process ended early"
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    assert 1 < len(out.read_text().splitlines()) < len(full_run.splitlines())
    sweep.run_sweep(SPEC, out, memory_budget_mb=budget, progress=False)
    assert out.read_text() == full_run


def test_resume_drops_a_torn_row_inside_a_written_chunk(tmp_path, full_run, budget):
    out = tmp_path / "torn.csv"
    lines = full_run.splitlines(keepends=True)
    out.write_text("".join(lines[:7]) + lines[7][:5])   # chunk 2 cut inside its third row
    sweep.run_sweep(SPEC, out, memory_budget_mb=budget, progress=False)
    assert out.read_text() == full_run


def test_cli_sweep_from_toml_resumes_a_partial_file(tmp_path, full_run, budget, capsys):
    spec = tmp_path / "sweep.toml"
    spec.write_text(TOML)
    out = tmp_path / "cli.csv"
    out.write_text("".join(full_run.splitlines(keepends=True)[:5]))
    assert main(["sweep", str(spec), "--out", str(out), "--memory-budget-mb", str(budget), "--no-progress"]) == 0
    assert out.read_text() == full_run
    assert "wrote" in capsys.readouterr().out


def test_cli_sweep_help_and_bad_spec(tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        main(["sweep", "--help"])
    assert info.value.code == 0 and "resumes" in capsys.readouterr().out
    bad = tmp_path / "bad.toml"
    bad.write_text('scenes = ["default"]\n[fabric]\nk = [2, 4]\n')
    with pytest.raises(SystemExit) as info:
        main(["sweep", str(bad), "--out", str(tmp_path / "x.csv")])
    assert info.value.code == 2 and "fabric.k" in capsys.readouterr().err


@pytest.mark.parametrize("spec, match", [
    ({"scenes": ["default"], "fabrc": {}}, "fabrc: unknown key"),
    ({"scenes": ["default"], "fabric": {"theta": [1.0]}}, "fabric.theta: unknown field"),
    ({"scenes": ["default"], "fabric": {"k": [2]}}, "fabric.k: a static field"),
    ({"scenes": ["default"], "static": {"tau_h": 0.5}}, "static.tau_h: a traced field"),
    ({"scenes": ["default"], "fabric": {"tau_h": []}}, "fabric.tau_h: an empty list"),
    ({"scenes": ["default"], "fabric": {"tau_h": ["a"]}}, "fabric.tau_h: expected a finite number"),
    ({"scenes": ["default"], "fabric": {"theta_tol_deg": [200.0]}}, "FabricParams.theta_tol_deg"),
    ({"scenes": ["default"], "spill": {"lam": [-1.0]}}, "SpillParams.lam"),
    ({"scenes": ["nowhere.npz"]}, "scenes: 'nowhere.npz' is neither"),
    ({}, "scenes: no scenes"),
    ({"random_scenes": {"seeds": [], "shape": [5, 5]}}, "random_scenes.seeds"),
    ({"random_scenes": {"seeds": [1], "shape": [5]}}, "random_scenes.shape"),
    ({"random_scenes": {"seeds": [1], "density": 2.0}}, "random_scenes.density"),
    ({"scenes": ["default"], "metrics": {"top_sources": -1}}, "metrics.top_sources"),
])
def test_bad_spec_names_the_key(spec, match):
    with pytest.raises(ValueError, match=match):
        sweep.load_spec(spec)


def test_bad_arguments_and_foreign_files(tmp_path, budget):
    with pytest.raises(ValueError, match="backend"):
        sweep.run_sweep(SPEC, tmp_path / "a.csv", backend="spark")
    with pytest.raises(ValueError, match="memory_budget_mb"):
        sweep.run_sweep(SPEC, tmp_path / "a.csv", memory_budget_mb=0)
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="another sweep"):
        sweep.run_sweep(SPEC, other, memory_budget_mb=budget, progress=False)


def test_chunk_size_follows_the_memory_budget():
    scene = sweep.load_spec(SPEC).scenes[0][1]
    per = sweep.bytes_per_table(scene, per_table=4)
    assert per > sweep.bytes_per_table(scene, per_table=1) > 0
    assert sweep.chunk_size_for(scene, 10 * per / 2**20, per_table=4) == 10
    assert sweep.chunk_size_for(scene, 1e-9) == 1
    assert sweep.chunk_size_for(scene, 1e6, n_tables=4) == 4


def test_fields_that_change_the_table_come_first():
    spec = sweep.load_spec({"scenes": ["default"], "fabric": {"tau_h": [0.3, 0.5], "theta_tol_deg": [45.0, 60.0]}})
    assert [k for k, _ in spec.fabric_grid] == ["theta_tol_deg", "tau_h"]
    assert [s[1] for s in sweep.settings_of(spec)] == [(45.0, 0.3), (45.0, 0.5), (60.0, 0.3), (60.0, 0.5)]


def test_ray_backend_without_ray_says_how_to_install(tmp_path, monkeypatch, budget):
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)   # import ray -> ImportError
    with pytest.raises(ValueError, match=r"jaxplan\[distributed\]"):
        sweep.run_sweep(SPEC, tmp_path / "r.csv", backend="ray", memory_budget_mb=budget, progress=False)
