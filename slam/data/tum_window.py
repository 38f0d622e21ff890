"""A window of a TUM RGB-D sequence written as its own TUM folder, as the shared excerpts are made.

``write_window(seq, out, start, stop)`` keeps associated rgb/depth pairs ``start .. stop-1`` (0-based, in the
order of TUM's ``associate.py``: each rgb frame with the closest unused depth frame within 0.02 s) and writes:

::

    out/rgb.txt, depth.txt          the sequence's header lines + the kept entries, lines unchanged
    out/associations.txt            "rgb_ts rgb/file depth_ts depth/file", one line per pair
    out/groundtruth.txt             header + rows from 0.5 s before the first kept image to 0.5 s after the
    out/accelerometer.txt           last (so every frame has poses on both sides for interpolation)
    out/rgb/*.png, depth/*.png      copies of the kept images
    out/SOURCE.md                   where the window comes from

``TUMDataset`` reads it through ``associations.txt``, so it loads exactly ``stop - start`` frames.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from slam.errors import SlamInputError

__all__ = ["associate", "write_window", "MAX_DIFFERENCE", "MARGIN_S"]

MAX_DIFFERENCE = 0.02  # associate.py's default, seconds
MARGIN_S = 0.5  # ground truth kept on each side of the window


def _read_lines(path: Path) -> tuple[list[str], list[tuple[float, str]]]:
    """``(header lines, [(timestamp, line)])`` of a TUM text file; '#' lines are the header."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise SlamInputError(f"{path}: cannot read ({exc})") from None
    header, rows = [], []
    for lineno, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            header.append(stripped)
            continue
        try:
            rows.append((float(stripped.split()[0]), stripped))
        except ValueError:
            raise SlamInputError(f"{path}:{lineno}: bad timestamp {stripped.split()[0]!r}") from None
    return header, rows


def associate(first: np.ndarray, second: np.ndarray, max_difference: float = MAX_DIFFERENCE) -> list[tuple[int, int]]:
    """TUM ``associate.py``: pairs ``(i, j)`` of ``first[i]`` and ``second[j]`` closer than ``max_difference``.

    Candidate pairs are taken closest first and each timestamp is used once; the result is sorted by
    ``first``. Takes two 1-D timestamp arrays (seconds); returns index pairs.
    """
    order = np.argsort(second, kind="stable")
    s = second[order]
    cand = []
    for i, a in enumerate(first):
        lo, hi = np.searchsorted(s, a - max_difference), np.searchsorted(s, a + max_difference, side="right")
        cand += [(abs(a - s[k]), a, s[k], i, int(order[k])) for k in range(lo, hi) if abs(a - s[k]) < max_difference]
    cand.sort()  # associate.py sorts (difference, a, b) tuples: the same order
    used_i, used_j, pairs = set(), set(), []
    for _, _, _, i, j in cand:
        if i not in used_i and j not in used_j:
            used_i.add(i)
            used_j.add(j)
            pairs.append((i, j))
    return sorted(pairs, key=lambda p: first[p[0]])


def _write_span(src: Path, dest: Path, lo: float, hi: float) -> None:
    """Copy ``src``'s header and the rows with ``lo <= timestamp <= hi`` to ``dest`` (skipped if src is absent)."""
    if not src.exists():
        return
    header, rows = _read_lines(src)
    dest.write_text("\n".join(header + [line for t, line in rows if lo <= t <= hi]) + "\n")


def _source_note(seq: Path, start: int, stop: int, n_pairs: int, first: str, last: str) -> str:
    """The window's SOURCE.md text: the sequence, the pair range of ``n_pairs`` and the first/last rgb stamps."""
    return (
        f"# {seq.name}, associated pairs {start}..{stop - 1}\n\n"
        f"Written by `lrslam download tum ... --frames {start}:{stop}` from the full sequence `{seq.name}` "
        f"({n_pairs} associated pairs, TUM associate.py, max difference {MAX_DIFFERENCE} s).\n\n"
        f"**Dataset:** TUM RGB-D SLAM Benchmark, https://cvg.cit.tum.de/data/datasets/rgbd-dataset. Cite J. Sturm, "
        f"N. Engelhard, F. Endres, W. Burgard, D. Cremers, \"A Benchmark for the Evaluation of RGB-D SLAM Systems\", "
        f"IROS 2012. License: CC BY 4.0.\n\n"
        f"**Contents:** `rgb.txt`, `depth.txt` (header lines kept, cut to these frames), `associations.txt` "
        f"(`rgb_ts rgb/file depth_ts depth/file`), `groundtruth.txt` and `accelerometer.txt` from {MARGIN_S} s "
        f"before to {MARGIN_S} s after the window, and copies of the {stop - start} rgb and depth images.\n\n"
        f"**Frames:** first rgb {first}, last rgb {last}.\n"
    )


def write_window(seq: Path, out: Path, start: int, stop: int) -> Path:
    """Write pairs ``start .. stop-1`` of the TUM sequence folder ``seq`` as a TUM folder ``out``.

    The folder is written beside ``out`` under a hidden name and renamed at the end, so ``out`` exists only
    when complete. Returns ``out``; SlamInputError if the range is empty or past the sequence's end.
    """
    rgb_header, rgb = _read_lines(seq / "rgb.txt")
    depth_header, depth = _read_lines(seq / "depth.txt")
    pairs = associate(np.array([t for t, _ in rgb]), np.array([t for t, _ in depth]))
    if not 0 <= start < stop <= len(pairs):
        raise SlamInputError(f"--frames {start}:{stop}: {seq.name} has {len(pairs)} associated rgb/depth pairs; "
                             f"expected 0 <= A < B <= {len(pairs)}")
    keep = pairs[start:stop]
    rgb_rows = [rgb[i] for i, _ in keep]
    depth_rows = sorted((depth[j] for _, j in keep), key=lambda r: r[0])
    tmp = out.with_name(f".{out.name}.writing")
    shutil.rmtree(tmp, ignore_errors=True)  # what an interrupted earlier attempt left
    try:
        _write_files(seq, tmp, rgb_header, depth_header, rgb_rows, depth_rows)
        assoc = [f"{rgb[i][1].split()[0]} {rgb[i][1].split()[1]} {depth[j][1].split()[0]} {depth[j][1].split()[1]}"
                 for i, j in keep]
        (tmp / "associations.txt").write_text("\n".join(assoc) + "\n")
        first, last = rgb_rows[0][1].split()[0], rgb_rows[-1][1].split()[0]
        (tmp / "SOURCE.md").write_text(_source_note(seq, start, stop, len(pairs), first, last))
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise SlamInputError(f"cannot write the window {out}: {exc}") from None
    tmp.replace(out)
    return out


def _write_files(seq: Path, tmp: Path, rgb_header, depth_header, rgb_rows, depth_rows) -> None:
    """Copy the kept images and write the index, ground-truth and accelerometer files of the window into
    ``tmp``; ``*_rows`` are ``(timestamp, line)`` of the kept entries. Raises OSError (missing image, full disk)."""
    for _, line in rgb_rows + depth_rows:
        rel = line.split()[1]
        (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(seq / rel, tmp / rel)
    (tmp / "rgb.txt").write_text("\n".join(rgb_header + [line for _, line in rgb_rows]) + "\n")
    (tmp / "depth.txt").write_text("\n".join(depth_header + [line for _, line in depth_rows]) + "\n")
    times = [t for t, _ in rgb_rows + depth_rows]
    lo, hi = min(times) - MARGIN_S, max(times) + MARGIN_S
    for name in ("groundtruth.txt", "accelerometer.txt"):
        _write_span(seq / name, tmp / name, lo, hi)
