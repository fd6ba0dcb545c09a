"""RunFolder: a manifest that says which files belong to the run, a rerun that removes exactly the
previous run's files and nothing outside the folder, one run per folder, and the status a run ends
with (complete, interrupted by a signal, failed)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from jaxplan.core.outputs import LOCK, MANIFEST, RunFolder, RunInterrupted, atomic_write, read_manifest
from jaxplan.core.signals import StopSignal


def _manifest(folder) -> dict:
    return json.loads((folder / MANIFEST).read_text())


def test_complete_run_lists_its_files(tmp_path):
    out = tmp_path / "a" / "b"
    with RunFolder(out, "demo", {"scene": "default", "fps": 4}) as run:
        assert _manifest(out)["status"] == "running"
        run.write_json("x.json", {"v": 1})
        assert _manifest(out)["files"] == ["x.json"]   # current after every file
        run.write(out / "y.bin", lambda fh: fh.write(b"\x00\x01"))
    m = _manifest(out)
    assert m["status"] == "complete" and m["error"] is None
    assert m["command"] == "demo" and m["arguments"] == {"scene": "default", "fps": 4}
    assert m["files"] == ["x.json", "y.bin"]
    assert m["finished"] is not None and m["started"] <= m["finished"]
    assert sorted(p.name for p in out.iterdir()) == sorted([MANIFEST, "x.json", "y.bin"])
    assert read_manifest(out) == m


def test_rerun_removes_the_previous_runs_files_but_not_the_users(tmp_path):
    with RunFolder(tmp_path, "demo") as run:
        run.write_json("summary.json", {})
        run.write("episode.gif", lambda fh: fh.write(b"GIF"))
        run.write("extra/notes.txt", lambda fh: fh.write(b"from the run"))
    (tmp_path / "mine.txt").write_text("the user's")
    with RunFolder(tmp_path, "demo") as run:
        assert not (tmp_path / "episode.gif").exists()        # listed by the old manifest
        assert not (tmp_path / "extra" / "notes.txt").exists()  # listed by the old manifest
        run.write_json("summary.json", {"new": True})
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([MANIFEST, "mine.txt", "summary.json"])
    assert _manifest(tmp_path)["files"] == ["summary.json"]


def test_folder_without_manifest_loses_nothing(tmp_path):
    (tmp_path / "episode.gif").write_bytes(b"old")
    (tmp_path / ".episode.gif.123.tmp.gif").write_bytes(b"the user's hidden file")
    with RunFolder(tmp_path, "episode"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([MANIFEST, "episode.gif", ".episode.gif.123.tmp.gif"])


def test_a_killed_writers_temp_files_of_listed_outputs_are_removed(tmp_path):
    with RunFolder(tmp_path, "episode") as run:
        run.write("episode.gif", lambda fh: fh.write(b"GIF"))
    (tmp_path / ".episode.gif.123.tmp.gif").write_bytes(b"killed writer (staged)")
    (tmp_path / ".episode.gif.ab_cd123.tmp").write_bytes(b"killed writer (atomic)")
    (tmp_path / ".episode.gif.notes").write_bytes(b"the user's")
    with RunFolder(tmp_path, "episode"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([MANIFEST, ".episode.gif.notes"])


def test_tampered_manifest_cannot_remove_files_outside_the_folder(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("safe")
    (out / MANIFEST).write_text(json.dumps({"format": "jaxplan.run", "files": ["../victim.txt", str(victim),
                                                                              7, None]}))
    with RunFolder(out, "demo"):
        pass
    assert victim.read_text() == "safe"


def _planted(out, files) -> None:
    (out / MANIFEST).write_text(json.dumps({"format": "jaxplan.run", "version": 1, "command": "episode",
                                            "arguments": {}, "status": "complete", "started": None,
                                            "finished": None, "files": files, "error": None}))


def test_a_symlinked_folder_in_the_manifest_is_not_followed(tmp_path):
    """The defect: a planted run.json listing ext/precious.txt, ext a link to a folder outside."""
    out, victim = tmp_path / "out", tmp_path / "victim"
    out.mkdir()
    victim.mkdir()
    (victim / "precious.txt").write_text("keep")
    (out / "ext").symlink_to(victim)
    _planted(out, ["ext/precious.txt"])
    with RunFolder(out, "episode"):
        pass
    assert (victim / "precious.txt").read_text() == "keep"


def test_a_symlinked_file_in_the_manifest_is_neither_followed_nor_removed(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "precious.txt"
    victim.write_text("keep")
    (out / "summary.json").symlink_to(victim)
    _planted(out, ["summary.json"])
    with RunFolder(out, "episode"):
        pass
    assert victim.read_text() == "keep" and (out / "summary.json").is_symlink()


def test_the_folder_reached_through_a_symlink_still_cleans_its_own_files(tmp_path):
    real = tmp_path / "real"
    with RunFolder(real, "episode") as run:
        run.write_json("metrics.json", {})
    (tmp_path / "alias").symlink_to(real)
    with RunFolder(tmp_path / "alias", "episode"):
        assert not (real / "metrics.json").exists()


def test_a_run_json_that_is_not_jaxplans_is_refused_and_kept(tmp_path):
    (tmp_path / MANIFEST).write_text('{"their": "data"}')
    (tmp_path / "theirs.txt").write_text("x")
    with pytest.raises(ValueError, match="did not write"), RunFolder(tmp_path, "episode"):
        pass
    assert (tmp_path / MANIFEST).read_text() == '{"their": "data"}' and (tmp_path / "theirs.txt").exists()
    assert not (tmp_path / LOCK).exists()


def test_a_second_run_into_a_folder_in_use_is_refused(tmp_path):
    with RunFolder(tmp_path, "episode") as run:
        run.write_json("metrics.json", {"first": True})
        holder = json.loads((tmp_path / LOCK).read_text())
        assert holder == {"pid": os.getpid(), "command": "episode"}
        # another process, so that the kernel's lock is really contended
        code = ("import sys; from jaxplan.core.outputs import RunFolder\n"
                "try:\n    RunFolder(sys.argv[1], 'demo').__enter__()\n"
                "except ValueError as e:\n    print(e); sys.exit(2)")
        other = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True)
        assert other.returncode == 2 and f"pid {os.getpid()}" in other.stdout and "episode" in other.stdout
        assert _manifest(tmp_path)["files"] == ["metrics.json"]   # the second run touched nothing
    assert not (tmp_path / LOCK).exists()


def test_the_lock_of_a_killed_run_is_taken_over_with_a_warning(tmp_path, capsys):
    (tmp_path / LOCK).write_text(json.dumps({"pid": 999_999_999, "command": "fleet"}))
    with RunFolder(tmp_path, "episode") as run:
        run.write_json("metrics.json", {})
    err = capsys.readouterr().err
    assert "taking over the lock" in err and "pid 999999999" in err
    assert not (tmp_path / LOCK).exists()


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_is_an_interrupted_run_that_names_it(tmp_path, signum):
    with pytest.raises(RunInterrupted) as info:
        with RunFolder(tmp_path, "episode") as run:
            run.write_json("metrics.json", {})
            raise StopSignal(signum)
    assert info.value.signum == signum
    m = _manifest(tmp_path)
    assert m["status"] == "interrupted" and signal.Signals(signum).name in m["error"]


def test_interrupted_run_says_so_and_keeps_its_partial_files(tmp_path):
    with pytest.raises(RunInterrupted) as info:
        with RunFolder(tmp_path, "episode") as run:
            run.write_json("metrics.json", {})
            raise KeyboardInterrupt
    assert isinstance(info.value, KeyboardInterrupt)
    assert str(tmp_path) in str(info.value) and "interrupted" in str(info.value)
    m = _manifest(tmp_path)
    assert m["status"] == "interrupted" and m["files"] == ["metrics.json"] and m["finished"]


def test_failed_run_records_the_error_and_reraises_it(tmp_path):
    with pytest.raises(ZeroDivisionError):
        with RunFolder(tmp_path, "episode"):
            1 / 0  # noqa: B018
    m = _manifest(tmp_path)
    assert m["status"] == "failed" and m["error"].startswith("ZeroDivisionError")


def test_staged_file_appears_only_when_complete(tmp_path):
    with RunFolder(tmp_path, "episode") as run:
        with run.staged("anim.gif") as tmp:
            assert tmp.suffix == ".gif" and tmp.parent == tmp_path
            tmp.write_bytes(b"GIF89a")
            assert not (tmp_path / "anim.gif").exists()
        with pytest.raises(RuntimeError), run.staged("broken.gif") as tmp:
            tmp.write_bytes(b"GIF")
            raise RuntimeError("writer failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["anim.gif", MANIFEST])
    assert _manifest(tmp_path)["files"] == ["anim.gif"]


@pytest.mark.parametrize("name", ["../up.txt", "/abs/x.txt", MANIFEST, ""])
def test_names_outside_the_folder_or_the_manifest_itself_are_refused(tmp_path, name):
    with RunFolder(tmp_path / "o", "demo") as run, pytest.raises(ValueError, match="not a file name"):
        run.write(name, lambda fh: fh.write(b"x"))


def test_a_file_in_place_of_the_folder_is_a_named_error(tmp_path):
    blocker = tmp_path / "out"
    blocker.write_text("a file")
    with pytest.raises(ValueError, match="not a directory"), RunFolder(blocker, "demo"):
        pass
    assert blocker.read_text() == "a file"


def test_atomic_write_leaves_nothing_when_the_writer_fails(tmp_path):
    target = tmp_path / "f.bin"
    target.write_bytes(b"old")

    def broken(fh):
        fh.write(b"partial")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        atomic_write(target, broken)
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["f.bin"]
