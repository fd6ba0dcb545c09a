"""Output folders of the CLI: each run's run.json lists its files, a rerun never leaves an earlier
run's files beside its own and deletes nothing outside the folder, one run at a time per folder,
Ctrl-C or SIGTERM exits 128 + the signal with the folder marked interrupted, and bad input leaves the
folder as it was."""
from __future__ import annotations

import json
import signal

import pytest

from jaxplan.cli import main
from jaxplan.cli import transport as cli_transport
from jaxplan.core.outputs import MANIFEST

# Every episode of this module, in this process and in the subprocesses, runs the default scene under the
# capacity-aware spill model with a blade that carries at most 0.01 objects: the same compiled programs
# (the push budget and the stop fraction are not compiled in), so the subprocesses load what the
# ``earlier_run`` fixture compiled from the persistent cache; and a push delivers at most about 0.01
# objects (the overflow spills beside the route), so clearing the scene's 505 objects would take over
# 50,000 pushes: the long episodes below cannot end on their own within the tests' waits.
SCENE = ["--scene", "default", "--capacity", "0.01"]
EPISODE = ["episode", *SCENE, "--max-pushes", "1"]
LONG_EPISODE = ["episode", *SCENE, "--stop-fraction", "0", "--max-pushes", "100000"]


def _files(folder) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def _manifest(folder) -> dict:
    return json.loads((folder / MANIFEST).read_text())


@pytest.fixture(scope="module")
def earlier_run(tmp_path_factory):
    """A folder holding a complete episode run with its animation."""
    out = tmp_path_factory.mktemp("earlier") / "out"
    assert main([*EPISODE, "--out", str(out)]) == 0
    return out


def _copy(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst


def test_manifest_of_a_complete_run(earlier_run):
    m = _manifest(earlier_run)
    assert m["status"] == "complete" and m["command"] == "episode"
    assert m["arguments"]["max_pushes"] == 1 and m["arguments"]["scene"] == "default"
    assert m["arguments"]["capacity"] == 0.01
    assert sorted(m["files"]) == sorted(f for f in _files(earlier_run) if f != MANIFEST)
    assert "episode.gif" in m["files"] and "summary.json" in m["files"]


def test_rerun_without_animation_drops_the_old_gif(earlier_run, tmp_path, capsys):
    out = _copy(earlier_run, tmp_path / "out")
    assert main([*EPISODE, "--no-animation", "--out", str(out)]) == 0
    m = _manifest(out)
    assert m["status"] == "complete" and "episode.gif" not in m["files"]
    assert _files(out) == sorted([MANIFEST, *m["files"]])


def test_interrupted_episode_exits_130_and_marks_the_folder(earlier_run, tmp_path, monkeypatch, capsys):
    out = _copy(earlier_run, tmp_path / "out")
    (out / "my_notes.txt").write_text("kept")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_transport, "_run_episode", interrupted)
    with pytest.raises(SystemExit) as info:
        main([*EPISODE, "--out", str(out)])
    assert info.value.code == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("interrupted: ") and str(out) in err[0]
    m = _manifest(out)
    assert m["status"] == "interrupted" and m["files"] == []
    assert _files(out) == sorted([MANIFEST, "my_notes.txt"])   # no earlier summary.json or episode.gif


def test_interrupted_demo_keeps_only_its_own_fabric_part(earlier_run, tmp_path, monkeypatch, capsys):
    out = _copy(earlier_run, tmp_path / "out")
    monkeypatch.setattr(cli_transport, "_run_episode", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))
    with pytest.raises(SystemExit) as info:
        main(["demo", "--max-pushes", "1", "--out", str(out)])
    assert info.value.code == 130
    m = _manifest(out)
    assert m["status"] == "interrupted" and m["command"] == "demo"
    assert sorted(m["files"]) == ["fabric.png", "summary.json"]
    assert _files(out) == sorted([MANIFEST, "fabric.png", "summary.json"])
    assert "episode" not in json.loads((out / "summary.json").read_text())


def test_bad_input_leaves_the_folder_as_it_was(earlier_run, tmp_path, capsys):
    out = _copy(earlier_run, tmp_path / "out")
    before = {f: (out / f).read_bytes() for f in _files(out)}
    with pytest.raises(SystemExit) as info:
        main([*EPISODE, "--theta-tol", "500", "--out", str(out)])
    assert info.value.code == 2
    assert {f: (out / f).read_bytes() for f in _files(out)} == before


def test_failed_write_marks_the_run_failed(tmp_path, monkeypatch, capsys):
    def no_space(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(cli_transport, "_episode_files", no_space)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as info:
        main([*EPISODE, "--no-animation", "--out", str(out)])
    assert info.value.code == 2
    assert "--out" in capsys.readouterr().err
    m = _manifest(out)
    assert m["status"] == "failed" and "No space left" in m["error"]


def _start_long_episode(out):
    """A real ``jaxplan episode`` process that cannot end on its own within the tests' waits, however
    warm the compilation cache (``LONG_EPISODE``: every object down to the last, 0.01 per push), and
    the list its stderr is read into."""
    import os
    import subprocess
    import sys
    import threading

    proc = subprocess.Popen([sys.executable, "-m", "jaxplan.cli", *LONG_EPISODE, "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env={**os.environ, "JAX_PLATFORMS": "cpu"})
    chunks: list[bytes] = []
    threading.Thread(target=lambda: chunks.extend(iter(lambda: proc.stderr.read1(4096), b"")), daemon=True).start()
    return proc, chunks


def _wait_for_the_first_push(proc, chunks) -> None:
    import re
    import time

    pushed = re.compile(rb"pushes:[^\r\n]*\| *[1-9][0-9]*/")
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and proc.poll() is None and not pushed.search(b"".join(chunks)):
        time.sleep(0.1)


def _interrupted_by(proc, chunks, signum, out) -> None:
    """Send ``signum`` to the running episode: it exits 128 + signum, the folder marked interrupted."""
    proc.send_signal(signum)
    proc.wait(timeout=120)
    err = b"".join(chunks).decode(errors="replace")
    assert proc.returncode == 128 + signum, err
    assert err.strip().splitlines()[-1].startswith("interrupted: ")
    m = _manifest(out)
    assert m["status"] == "interrupted" and signal.Signals(signum).name in m["error"]
    assert _files(out) == sorted([MANIFEST, *m["files"]])


def test_ctrl_c_mid_episode(earlier_run, tmp_path):
    """Ctrl-C delivered to a real process after its first push (read off the progress bar)."""
    out = _copy(earlier_run, tmp_path / "out")
    proc, chunks = _start_long_episode(out)
    _wait_for_the_first_push(proc, chunks)
    _interrupted_by(proc, chunks, signal.SIGINT, out)


def test_a_busy_folder_refuses_a_second_run_and_sigterm_stops_the_first(tmp_path, capsys):
    """While an episode runs, a second run into its folder exits 2 naming the first's pid; then the
    SIGTERM of ``timeout`` / systemd / Slurm / docker stops the first like Ctrl-C (exit 143)."""
    out = tmp_path / "out"
    proc, chunks = _start_long_episode(out)
    try:
        _wait_for_the_first_push(proc, chunks)
        with pytest.raises(SystemExit) as info:
            main([*EPISODE, "--no-animation", "--out", str(out)])
        assert info.value.code == 2
        err = capsys.readouterr().err
        assert "--out" in err and f"pid {proc.pid}" in err and "in use" in err
        assert _manifest(out)["command"] == "episode" and _manifest(out)["status"] == "running"
    finally:
        _interrupted_by(proc, chunks, signal.SIGTERM, out)


def test_a_rerun_deletes_nothing_outside_the_folder(tmp_path, capsys):
    """The defect as reported: a planted run.json lists a file behind a symlinked folder."""
    out, victim = tmp_path / "out", tmp_path / "victim"
    out.mkdir()
    victim.mkdir()
    (victim / "precious.txt").write_text("keep")
    (out / "ext").symlink_to(victim)
    (out / MANIFEST).write_text(json.dumps({
        "format": "jaxplan.run", "version": 1, "command": "episode", "arguments": {}, "status": "complete",
        "started": None, "finished": None, "files": ["ext/precious.txt"], "error": None}))
    assert main([*EPISODE, "--no-animation", "--out", str(out)]) == 0
    assert (victim / "precious.txt").read_text() == "keep"


def test_interrupted_sweep_says_how_many_rows_are_kept(tmp_path, monkeypatch, capsys):
    import jaxplan.sweep

    out = tmp_path / "s.csv"

    def interrupted_after_two_rows(spec, path, **kwargs):
        out.write_text("setting,scene\n0,default\n1,default\n")
        raise KeyboardInterrupt

    monkeypatch.setattr(jaxplan.sweep, "run_sweep", interrupted_after_two_rows)
    with pytest.raises(SystemExit) as info:
        main(["sweep", str(tmp_path / "spec.toml"), "--out", str(out), "--no-progress"])
    assert info.value.code == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"interrupted: {str(out)!r} keeps the 2 complete row(s) written so far; run the same "
                   "command again to resume."]


def test_a_sweep_that_fills_the_disk_names_the_file_and_the_flag(tmp_path, monkeypatch, capsys):
    """The defect: it said only ``error: File too large``."""
    import errno

    import jaxplan.sweep

    out = tmp_path / "s.csv"

    def disk_full_after_one_row(spec, path, **kwargs):
        out.write_text("setting,scene\n0,default\n")
        raise OSError(errno.EFBIG, "File too large")

    monkeypatch.setattr(jaxplan.sweep, "run_sweep", disk_full_after_one_row)
    with pytest.raises(SystemExit) as info:
        main(["sweep", str(tmp_path / "spec.toml"), "--out", str(out), "--no-progress"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: --out: could not write {str(out)!r} (File too large)")
    assert "1 complete row(s)" in err[0]


@pytest.mark.parametrize("argv", [
    ["fabric", "--scene", "x" * 300 + ".npz", "--out", "f.npz"],
    ["episode", "--scene", "default", "--out", "x" * 300],
    ["pusharound", "--scene", "x" * 300 + ".json", "--out", "o"],
    ["pusharound", "--mode-table", "x" * 300 + ".json", "--out", "o"],
    ["sweep", "x" * 300 + ".toml", "--out", "s.csv"],
])
def test_paths_the_system_cannot_look_up_are_one_line(argv, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "is not a usable path" in err[0], err
    assert list(tmp_path.iterdir()) == []
