"""The kernel cache folder: when the user's cache folder cannot be written, the fallback under the system's
temporary folder is this user's alone (the kernels are imported from it and numba's cache index beside them is a
pickle: a folder another user can write would let them run code as this one)."""

import logging
import os
import stat

import pytest

from tdfields.kernels import cache
from tdfields.kernels.numba import source as numba_source


@pytest.fixture
def tmpdir_fallback(tmp_path, monkeypatch):
    """The user's cache folder unwritable (its parent is a file) and the system's temporary folder ``tmp/``: the
    predictable fallback's path is returned."""
    (tmp_path / "a file").write_text("")
    monkeypatch.setenv("TDFIELDS_CACHE_DIR", str(tmp_path / "a file" / "cache"))
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(cache.tempfile, "gettempdir", lambda: str(tmp))
    monkeypatch.setattr(cache.tempfile, "tempdir", str(tmp))  # where mkdtemp makes its folders
    return tmp / f"tdfields-kernels-v{numba_source.KERNEL_VERSION}-{os.getuid()}"


def _private(folder):
    st = os.lstat(folder)
    return stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid() and stat.S_IMODE(st.st_mode) == 0o700


def test_the_fallback_folder_is_created_private(tmpdir_fallback):
    assert cache.cache_dir() == tmpdir_fallback
    assert _private(tmpdir_fallback)
    assert cache.cache_dir() == tmpdir_fallback  # ours: taken again by the next call


def test_a_fallback_folder_others_can_write_is_not_used(tmpdir_fallback, caplog):
    tmpdir_fallback.mkdir()
    os.chmod(tmpdir_fallback, 0o777)  # made by someone else with a wide umask, or left so
    (tmpdir_fallback / "planted.py").write_text("")
    with caplog.at_level(logging.WARNING, logger="tdfields"):
        got = cache.cache_dir()
    assert got != tmpdir_fallback and _private(got) and not any(got.iterdir())
    assert "group or other users can write" in caplog.text and str(tmpdir_fallback) in caplog.text
    assert cache.cache_dir() == got  # one fresh folder for the process, not one per kernel


def test_a_fallback_folder_of_another_user_is_not_used(tmpdir_fallback, monkeypatch, caplog):
    tmpdir_fallback.mkdir(mode=0o700)
    me = os.getuid()
    # the folder as another user would have made it: its owner is not the uid this process runs as
    monkeypatch.setattr(cache.os, "getuid", lambda: me + 1)
    planted = tmpdir_fallback.with_name(f"tdfields-kernels-v{numba_source.KERNEL_VERSION}-{me + 1}")
    tmpdir_fallback.rename(planted)
    with caplog.at_level(logging.WARNING, logger="tdfields"):
        got = cache.cache_dir()
    assert got != planted and got.parent == planted.parent
    assert f"owned by uid {me}" in caplog.text


def test_a_symbolic_link_in_place_of_the_fallback_folder_is_not_followed(tmpdir_fallback, tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir(mode=0o700)
    tmpdir_fallback.symlink_to(elsewhere)
    got = cache.cache_dir()
    assert got not in (tmpdir_fallback, elsewhere) and _private(got)
