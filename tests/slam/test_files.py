"""Writing a run's files (slam/files.py): flushed to the disk before and after the rename, and a failed write (a full
disk) leaves the previous file as it was, with one line naming the file."""

import errno
import os

import pytest

from slam.errors import SlamOutputError
from slam.files import atomic_write_text, replacing


def _fsynced(monkeypatch) -> list[str]:
    """Record the path of every descriptor ``os.fsync`` is called on."""
    seen = []
    real = os.fsync

    def spy(fd):
        seen.append(os.readlink(f"/proc/self/fd/{fd}"))
        return real(fd)

    monkeypatch.setattr(os, "fsync", spy)
    return seen


def test_a_replaced_file_is_flushed_then_its_folder(tmp_path, monkeypatch):
    seen = _fsynced(monkeypatch)
    target = tmp_path / "metrics.json"
    atomic_write_text(target, "{}")
    # the data first (under its temporary name), then the folder holding the rename
    assert seen == [str(tmp_path / ".metrics.tmp.json"), str(tmp_path)]
    assert target.read_text() == "{}" and sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json"]


def test_a_full_disk_keeps_the_old_file_and_says_which_one(tmp_path):
    target = tmp_path / "trajectory.txt"
    target.write_text("old")
    with pytest.raises(SlamOutputError) as info:
        with replacing(target, "trajectory") as tmp:
            tmp.write_text("half")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert str(info.value) == (f"{target}: trajectory not written (No space left on device); the previous file, if "
                               "any, is intact")
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["trajectory.txt"]
