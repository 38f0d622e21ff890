"""Writing a run's files so that neither a kill, a power loss nor a full disk loses what was written before.

Every output goes to a temporary name in the same folder, is flushed to the disk (``fsync``), and is renamed over
the old file, after which the folder itself is flushed so the rename survives a power loss too. A reader, or a run
killed at any point, sees the old file or the new one, never a half-written or empty one. A write that fails (a
full disk, a read-only folder) removes its temporary file and raises :class:`slam.errors.SlamOutputError` naming
the file; the file it would have replaced is untouched.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Iterator

from slam.errors import SlamOutputError


def fsync_file(path: Path) -> None:
    """Flush a written file's data to the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(folder: Path) -> None:
    """Flush a folder's entries (a rename into it) to the disk; a no-op where folders cannot be opened."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # e.g. Windows: no directory handles
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some filesystems refuse fsync on a directory; the rename is then as durable as they make it
    finally:
        os.close(fd)


@contextlib.contextmanager
def replacing(path: str | Path, what: str = "output") -> Iterator[Path]:
    """``with replacing(path) as tmp:`` write ``tmp``; on leaving, ``tmp`` is flushed and renamed onto ``path``.

    Raises:
        SlamOutputError: the write failed (``OSError``: a full disk, no permission); ``path`` is as it was.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")  # the suffix stays: writers pick the format by it
    try:
        yield tmp
        fsync_file(tmp)
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        reason = exc.strerror or str(exc)
        raise SlamOutputError(f"{path}: {what} not written ({reason}); the previous file, if any, is intact") from None
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def atomic_write_text(path: str | Path, text: str, what: str = "output") -> None:
    """Write ``text`` to ``path`` through :func:`replacing`."""
    with replacing(path, what) as tmp:
        tmp.write_text(text)
