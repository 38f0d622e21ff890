"""The TUM RGB-D text files: one reader for their lines, and the three kinds of file built on it.

::

    rgb.txt, depth.txt      "timestamp file"                          (read_tum_list)
    groundtruth.txt         "timestamp tx ty tz qx qy qz qw"          (read_tum_poses; also every trajectory
                                                                       slam.eval reads: the same format)
    associations.txt        "rgb_ts rgb_file depth_ts depth_file"     (read_associations)

Blank lines and lines starting with ``#`` are skipped. Every bad line raises
:class:`~slam.errors.SlamInputError` naming the file and the line number.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slam.errors import SlamInputError

__all__ = ["ASSOCIATION_FILES", "POSE_COLUMNS", "read_associations", "read_rows", "read_tum_list", "read_tum_poses"]

#: the names an associations file goes by (TUM's associate.py writes whatever it is told)
ASSOCIATION_FILES = ("associations.txt", "associate.txt")
POSE_COLUMNS = "timestamp tx ty tz qx qy qz qw"


def read_rows(path: Path, commas: bool = False) -> list[tuple[int, list[str]]]:
    """``(line number, fields)`` of every line of ``path`` that is neither blank nor a ``#`` comment; fields
    are split on white space (and on commas with ``commas``). SlamInputError if the file cannot be read."""
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        raise SlamInputError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SlamInputError(f"{path}: cannot read ({exc})") from None
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        rows.append((lineno, (line.replace(",", " ") if commas else line).split()))
    return rows


def read_tum_list(path: Path) -> tuple[np.ndarray, list[str]]:
    """Read a TUM ``timestamp file`` list as ``(timestamps [N] float64, files)``; SlamInputError if bad."""
    ts, files = [], []
    for lineno, parts in read_rows(path):
        if len(parts) < 2:
            raise SlamInputError(f"{path}:{lineno}: expected 'timestamp filename'")
        try:
            ts.append(float(parts[0]))
        except ValueError:
            raise SlamInputError(f"{path}:{lineno}: bad timestamp {parts[0]!r}") from None
        files.append(parts[1])
    return np.asarray(ts, dtype=np.float64), files


def read_tum_poses(path: str | Path, what: str = "pose") -> np.ndarray:
    """The rows ``timestamp tx ty tz qx qy qz qw`` of a TUM pose file as ``[N, 8]`` float64, in file order.

    Columns past the eighth are ignored; commas count as white space. ``what`` names a row in the messages
    (``pose``, ``ground-truth row``). Raises :class:`SlamInputError` for a missing or unreadable file, a line
    with fewer than 8 columns or a non-numeric value (naming the line), no rows at all, a NaN or infinite value,
    or a quaternion far from unit length (a sign of a wrong column order).
    """
    path = Path(path)
    values, lines = [], []
    for lineno, parts in read_rows(path, commas=True):
        if len(parts) < 8:
            raise SlamInputError(f"{path}:{lineno}: expected 8 columns '{POSE_COLUMNS}', got {len(parts)}")
        try:
            values.append([float(v) for v in parts[:8]])
        except ValueError as exc:
            raise SlamInputError(f"{path}:{lineno}: non-numeric value ({exc})") from None
        lines.append(lineno)
    if not values:
        raise SlamInputError(f"{path}: no poses (empty trajectory)")
    data = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(data).all(axis=1)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise SlamInputError(f"{path}: {what} {bad} contains NaN or inf (line {lines[bad]}, "
                             f"timestamp {data[bad, 0]:.6f})")
    qn = np.linalg.norm(data[:, 4:8], axis=1)
    if np.any(np.abs(qn - 1.0) > 0.01):
        bad = int(np.flatnonzero(np.abs(qn - 1.0) > 0.01)[0])
        raise SlamInputError(f"{path}: {what} {bad} has quaternion norm {qn[bad]:.4f} (line {lines[bad]}); "
                             f"expected unit quaternions in the TUM column order '{POSE_COLUMNS}'")
    return data


def read_associations(path: Path) -> tuple[np.ndarray, list[str], list[str]]:
    """``(rgb timestamps [N], rgb files, depth files)`` of an associations file (pairs written depth-first are
    swapped); SlamInputError on a bad line or a file without pairs."""
    rgb_ts, rgb_files, depth_files = [], [], []
    for lineno, parts in read_rows(path):
        if len(parts) < 4:
            raise SlamInputError(f"{path}:{lineno}: expected 'rgb_ts rgb_file depth_ts depth_file'")
        a_ts, a_file, b_ts, b_file = parts[:4]
        if a_file.startswith("depth") and not b_file.startswith("depth"):
            a_ts, a_file, b_ts, b_file = b_ts, b_file, a_ts, a_file  # written depth-first
        try:
            rgb_ts.append(float(a_ts))
            float(b_ts)
        except ValueError:
            raise SlamInputError(f"{path}:{lineno}: bad timestamp") from None
        rgb_files.append(a_file)
        depth_files.append(b_file)
    if not rgb_ts:
        raise SlamInputError(f"{path}: empty association (no frame pairs)")
    return np.asarray(rgb_ts), rgb_files, depth_files
