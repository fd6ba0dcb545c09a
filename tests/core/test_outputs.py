"""RunFolder: a manifest that says which files belong to the run, a rerun that removes the previous
run's files, and the status a run ends with (complete, interrupted, failed)."""
from __future__ import annotations

import json

import pytest

from jaxplan.core.outputs import MANIFEST, RunFolder, RunInterrupted, atomic_write, read_manifest


def _manifest(folder) -> dict:
    return json.loads((folder / MANIFEST).read_text())


def test_complete_run_lists_its_files(tmp_path):
    out = tmp_path / "a" / "b"
    with RunFolder(out, "demo", {"scene": "default", "fps": 4}, outputs=("x.json", "y.bin")) as run:
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
    with RunFolder(tmp_path, "demo", outputs=("summary.json", "episode.gif")) as run:
        run.write_json("summary.json", {})
        run.write("episode.gif", lambda fh: fh.write(b"GIF"))
        run.write("extra/notes.txt", lambda fh: fh.write(b"from the run"))
    (tmp_path / "mine.txt").write_text("the user's")
    with RunFolder(tmp_path, "demo", outputs=("summary.json", "episode.gif")) as run:
        assert not (tmp_path / "episode.gif").exists()        # listed by the old manifest and named
        assert not (tmp_path / "extra" / "notes.txt").exists()  # listed by the old manifest
        run.write_json("summary.json", {"new": True})
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([MANIFEST, "mine.txt", "summary.json"])
    assert _manifest(tmp_path)["files"] == ["summary.json"]


def test_folder_without_manifest_loses_only_the_commands_names(tmp_path):
    (tmp_path / "episode.gif").write_bytes(b"old")
    (tmp_path / ".episode.gif.123.tmp.gif").write_bytes(b"killed writer")
    (tmp_path / "keep.gif").write_bytes(b"not ours")
    with RunFolder(tmp_path, "episode", outputs=("episode.gif",)):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([MANIFEST, "keep.gif"])


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
