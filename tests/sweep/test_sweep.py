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
    # accepted once, but ignored: every row was equal
    ({"scenes": ["default"], "fabric": {"temperature": [0.0, 0.5]}},
     "fabric.temperature: not sweepable: sweeps build the hard fabric"),
    ({"scenes": ["default"], "fabric": {"anchor_lambda": [0.5, 2.0]}},
     "fabric.anchor_lambda: not sweepable: it only weighs connectors"),
    ({"scenes": ["default"], "static": {"temperature": 0.5}}, "static.temperature: not sweepable"),
    ({"scenes": ["default"], "static": {"soft_rounds": 8}}, "static.soft_rounds: not sweepable"),
    ({"scenes": ["default"], "spill": {"lam": [0.0, 0.1]}, "metrics": {"top_sources": 0}},
     "spill.lam: metrics.top_sources = 0 turns the route metrics off"),
    ({"scenes": ["default"], "fabric": {"slack_tau": [0.0, 1.0]}, "metrics": {"top_sources": 0}},
     "fabric.slack_tau: metrics.top_sources = 0"),
    ({"scenes": ["default"], "static": {"samples_per_step": 4}, "metrics": {"top_sources": 0}},
     "static.samples_per_step: metrics.top_sources = 0"),
    ({"scenes": ["default"], "spill": {"threshold": [0.0, 1.0]}, "static": {"enabled": False}},
     "spill.threshold: static.enabled = false"),
    ({"scenes": ["default"], "fabric": {"slack_tau": [0.0, 1.0]}, "static": {"enabled": False}},
     "fabric.slack_tau: static.enabled = false"),
    ({"scenes": ["default"], "static": {"k": 25}}, r"FabricParams.k: 25 is out of range"),
])
def test_bad_spec_names_the_key(spec, match):
    with pytest.raises(ValueError, match=match):
        sweep.load_spec(spec)


def test_unknown_field_lists_only_the_sweepable_ones():
    with pytest.raises(ValueError, match="sweepable fields are theta_tol_deg, tau_h, slack_tau.$") as info:
        sweep.load_spec({"scenes": ["default"], "fabric": {"temprature": [0.5]}})
    assert "anchor_lambda" not in str(info.value) and "temperature" not in str(info.value)


def test_every_params_field_is_sweepable_or_refused():
    """A field added to FabricParams must be listed as sweepable or refused with a reason."""
    import dataclasses

    from jaxplan.sweep import spec

    fields = {f.name for f in dataclasses.fields(FabricParams)}
    listed = set(spec.FABRIC_TRACED) | set(spec.FABRIC_STATIC) | set(spec.REFUSED)
    assert fields == listed
    assert not set(spec.REFUSED) & (set(spec.FABRIC_TRACED) | set(spec.FABRIC_STATIC))


def test_every_sweepable_traced_field_changes_a_metric(tmp_path):
    """Two values of each accepted [fabric] / [spill] field give rows that differ in some metric."""
    grid = {"fabric": {"theta_tol_deg": [20.0, 80.0], "tau_h": [0.05, 0.95], "slack_tau": [0.0, 30.0]},
            "spill": {"lam": [0.0, 0.5], "threshold": [0.0, 0.5], "temperature": [0.0, 2.0]}}
    assert {k for k, _ in grid["fabric"].items()} == set(sweep.spec.FABRIC_TRACED)
    assert set(grid["spill"]) == set(sweep.spec.SPILL_TRACED)
    out = tmp_path / "all.csv"
    sweep.run_sweep({"random_scenes": {"seeds": [5], "shape": [7, 7], "density": 0.8}, **grid,
                     "metrics": {"top_sources": 6}}, out, progress=False)
    header, rows = _rows(out.read_text())
    swept = [k for k in header[2:] if k not in sweep.METRICS]
    for field in swept:
        j = header.index(field)
        others = [i for i, k in enumerate(header) if k in swept and k != field]
        differs = False
        for r in rows:
            for q in rows:
                if r[j] < q[j] and all(r[i] == q[i] for i in others):
                    differs |= r[-len(sweep.METRICS):] != q[-len(sweep.METRICS):]
        assert differs, f"{field} changes no metric"


def test_cli_refuses_an_ignored_field_in_one_line(tmp_path, capsys):
    spec = tmp_path / "t.toml"
    spec.write_text('scenes = ["default"]\n[fabric]\ntemperature = [0.0, 0.5]\n')
    with pytest.raises(SystemExit) as info:
        main(["sweep", str(spec), "--out", str(tmp_path / "o.csv")])
    assert info.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: sweep spec: fabric.temperature: not sweepable")
    assert not (tmp_path / "o.csv").exists()


def test_bad_arguments_and_foreign_files(tmp_path, budget):
    with pytest.raises(ValueError, match="backend"):
        sweep.run_sweep(SPEC, tmp_path / "a.csv", backend="spark")
    for bad in (0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="memory_budget_mb"):
            sweep.run_sweep(SPEC, tmp_path / "a.csv", memory_budget_mb=bad)
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


def test_a_table_too_deep_for_memory_is_refused_before_the_file(tmp_path, monkeypatch):
    from jaxplan.transport import fabric

    monkeypatch.setattr(fabric, "available_memory_bytes", lambda: 10**9)
    out = tmp_path / "deep.csv"
    with pytest.raises(ValueError, match=r"FabricParams.k: K = 16 needs about 7.0 GB .* use k <= 10"):
        sweep.run_sweep({"scenes": ["default"], "static": {"k": 16}}, out, progress=False)
    assert not out.exists()
