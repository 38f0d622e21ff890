"""Resumable HTTP downloads with checksums, and safe unpacking of zip and tar archives.

Only the standard library (``urllib``, ``zipfile``, ``tarfile``, ``hashlib``) and tqdm. A download goes to
``<file>.part`` and is renamed to ``<file>`` only once it is complete and its checksum (when one is known)
matches, so a file without ``.part`` is always a whole, verified archive. Every failure a user can meet (the
network, a full disk, a bad checksum, an archive member that would land outside the target folder) raises
:class:`~slam.errors.SlamInputError` with a one-line message.
"""

from __future__ import annotations

import errno
import hashlib
import http.client
import re
import shutil
import tarfile
import urllib.error
import urllib.request
import zipfile
from pathlib import Path, PurePosixPath

from slam.errors import SlamInputError

__all__ = ["download", "unpack", "file_digest", "remove_tree"]

CHUNK = 1 << 20
TIMEOUT_S = 60.0  # seconds without a byte before a stalled connection counts as a network failure

_NETWORK_ERRORS = (urllib.error.URLError, http.client.HTTPException, ConnectionError, TimeoutError)


def _write(fh, data: bytes) -> None:
    """Write one downloaded chunk to the open ``.part`` file (a seam: the tests replace it to fill the disk)."""
    fh.write(data)


def _disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` is the OS saying the disk is full (ENOSPC)."""
    return isinstance(exc, OSError) and exc.errno == errno.ENOSPC


def file_digest(path: Path, algorithm: str = "sha256") -> str:
    """Hex digest of a file, read in 1 MiB chunks; ``algorithm`` is any :mod:`hashlib` name."""
    h = hashlib.new(algorithm)
    with open(path, "rb") as fh:
        while chunk := fh.read(CHUNK):
            h.update(chunk)
    return h.hexdigest()


def _open(url: str, offset: int):
    """The response to a GET of ``url`` asking for bytes from ``offset`` on (no Range header at 0)."""
    from slam import __version__

    headers = {"User-Agent": f"lrslam/{__version__}"}
    if offset:
        headers["Range"] = f"bytes={offset}-"
    return urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=TIMEOUT_S)


def _range_start(resp) -> int | None:
    """First byte of a 206 answer's ``Content-Range`` (``bytes START-END/TOTAL``), None if absent."""
    m = re.match(r"bytes\s+(\d+)-", resp.headers.get("Content-Range") or "")
    return int(m.group(1)) if m else None


def _response(url: str, part: Path):
    """``(response, offset)`` for the rest of ``url`` after the ``offset`` bytes already in ``part``; the response
    is None when ``part`` already holds the whole file.

    A server that ignores the Range header (200 instead of 206) sends the whole file, so the offset drops to 0
    and the partial file is rewritten; a 206 for another range than the one asked for is asked again from 0.
    """
    offset = part.stat().st_size if part.exists() else 0
    try:
        resp = _open(url, offset)
    except urllib.error.HTTPError as exc:
        if exc.code != 416 or not offset:
            raise
        # 416: nothing after our offset; "bytes */TOTAL" says whether the file was already complete
        m = re.search(r"/(\d+)", exc.headers.get("Content-Range") or "")
        if m and int(m.group(1)) == offset:
            return None, offset
        return _open(url, 0), 0
    if offset and (resp.status != 206 or _range_start(resp) != offset):
        if resp.status == 206:
            resp.close()
            resp = _open(url, 0)
        offset = 0
    return resp, offset


def _fetch(url: str, part: Path, desc: str) -> None:
    """Append the rest of ``url`` to ``part`` (created if missing), resuming from its size, with a progress bar
    labelled ``desc``. Raises the network's own exceptions (and ConnectionError on a short body); the caller
    turns them into one line."""
    from tqdm import tqdm

    resp, offset = _response(url, part)
    if resp is None:
        return
    with resp:
        length = resp.headers.get("Content-Length")
        total = offset + int(length) if length and length.isdigit() else None
        done = offset
        with open(part, "ab" if offset else "wb") as fh, tqdm(
            total=total, initial=offset, unit="B", unit_scale=True, unit_divisor=1024, desc=desc, leave=True,
        ) as bar:
            while chunk := resp.read(CHUNK):
                _write(fh, chunk)
                done += len(chunk)
                bar.update(len(chunk))
    if total is not None and done < total:
        raise ConnectionError(f"connection closed after {done} of {total} bytes")


def _download_error(exc: BaseException, url: str, part: Path) -> SlamInputError:
    """The one-line error for an exception raised while fetching ``url`` into ``part``."""
    if _disk_full(exc):
        have = part.stat().st_size if part.exists() else 0
        return SlamInputError(f"disk full while writing {part} ({have:,} bytes kept); free space and rerun the same "
                              f"command to resume")
    if isinstance(exc, urllib.error.HTTPError):
        reason = f"HTTP {exc.code} {exc.reason}"
    elif isinstance(exc, _NETWORK_ERRORS):
        reason = getattr(exc, "reason", None) or f"{type(exc).__name__}: {exc}"
    else:  # a local file problem (permissions, a read-only folder), not the network
        return SlamInputError(f"cannot write {part}: {getattr(exc, 'strerror', None) or exc}")
    have = part.stat().st_size if part.exists() else 0
    kept = f" (the {have:,} bytes in {part} are kept)" if have else ""
    return SlamInputError(f"download of {url} failed ({reason}); rerun the same command to resume{kept}")


def download(url: str, dest: Path, *, checksum: tuple[str, str] | None = None) -> Path:
    """Download ``url`` to ``dest`` through ``dest.part``, resuming a ``.part`` left by an earlier attempt.

    Args:
        url: http(s) address.
        dest: the final file; its folder is created.
        checksum: ``(algorithm, hex digest)``, e.g. ``("sha256", "ab12...")``, or None to skip verification.

    Returns ``dest``. Raises SlamInputError (one line) on a network failure (the ``.part`` is kept: rerunning
    resumes), a full disk (``.part`` kept), or a checksum mismatch (the download is deleted).
    """
    part = dest.with_name(dest.name + ".part")
    dest.parent.mkdir(parents=True, exist_ok=True)
    try:
        _fetch(url, part, dest.name)
    except (OSError, http.client.HTTPException) as exc:
        raise _download_error(exc, url, part) from None
    if checksum is not None:
        algorithm, expected = checksum[0], checksum[1].lower()
        got = file_digest(part, algorithm)
        if got != expected:
            part.unlink()  # resuming onto corrupt bytes could never succeed
            raise SlamInputError(f"{url}: {algorithm} mismatch (expected {expected}, got {got}); the download was "
                                 f"deleted, rerun to fetch it again")
    part.replace(dest)
    return dest


def _check_member(name: str, dest: Path, archive: Path) -> None:
    """Refuse an archive member whose path is absolute or climbs out of ``dest`` (path traversal)."""
    posix = PurePosixPath(name.replace("\\", "/"))
    bad = posix.is_absolute() or ".." in posix.parts or re.match(r"^[A-Za-z]:", name)
    if not bad:
        bad = not (dest / posix).resolve().is_relative_to(dest.resolve())
    if bad:
        raise SlamInputError(f"{archive}: member {name!r} would be written outside {dest}; refusing to unpack")


def _unpack_tar(archive: Path, dest: Path) -> None:
    """Unpack a tar (any compression) into ``dest`` after checking every member; links must stay inside too."""
    with tarfile.open(archive, "r:*") as tar:
        members = tar.getmembers()
        for m in members:
            _check_member(m.name, dest, archive)
            if m.issym() or m.islnk():
                target = m.linkname if m.islnk() else str(PurePosixPath(m.name).parent / m.linkname)
                _check_member(target, dest, archive)
            elif not (m.isfile() or m.isdir()):
                raise SlamInputError(f"{archive}: member {m.name!r} is a device or fifo; refusing to unpack")
        # Python's own "data" filter (3.10.12+) repeats these checks and also drops setuid bits
        extra = {"filter": "data"} if hasattr(tarfile, "data_filter") else {}
        tar.extractall(dest, members=members, **extra)


def unpack(archive: Path, dest: Path) -> None:
    """Unpack a ``.zip`` or a tar (``.tgz``, ``.tar.gz``, plain) archive into ``dest`` (created).

    Members that would land outside ``dest`` are refused before anything is written. Raises SlamInputError on
    an unreadable or unsafe archive, and on a full disk (whatever was unpacked is left for the caller to
    remove).
    """
    dest.mkdir(parents=True, exist_ok=True)
    try:
        if zipfile.is_zipfile(archive):
            with zipfile.ZipFile(archive) as zf:
                for name in zf.namelist():
                    _check_member(name, dest, archive)
                zf.extractall(dest)
        elif tarfile.is_tarfile(archive):
            _unpack_tar(archive, dest)
        else:
            raise SlamInputError(f"{archive}: not a zip or tar archive")
    except OSError as exc:
        if _disk_full(exc):
            raise SlamInputError(f"disk full while unpacking {archive} into {dest.parent}; free space and rerun "
                                 f"(the archive is kept)") from None
        raise SlamInputError(f"{archive}: cannot unpack ({exc})") from None
    except getattr(tarfile, "FilterError", ()) as exc:  # Python's data filter found what our checks missed
        raise SlamInputError(f"{archive}: unsafe member ({exc}); refusing to unpack") from None
    except (zipfile.BadZipFile, tarfile.TarError, EOFError) as exc:
        raise SlamInputError(f"{archive}: damaged archive ({type(exc).__name__}: {exc}); delete it and rerun")\
            from None


def remove_tree(path: Path) -> None:
    """Delete a folder left by an interrupted unpack (no error if it is already gone)."""
    shutil.rmtree(path, ignore_errors=True)
