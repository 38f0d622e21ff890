"""benchmarks/no_depth_study.py's measures, on trajectories with known errors (its SLAM runs take minutes): a
dropped frame's motion error is measured from the last frame before it that kept its depth, so drift before the
gap does not count; and the copy it runs on zeroes the depth of the dropped frames only, their colour kept."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from slam.eval import write_tum_trajectory
from tests.benchmarks.conftest import load_script

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "no_depth_study.py"
TUM_FAST = Path(__file__).resolve().parents[3] / "shared" / "data" / "tum_fr1_rpy_0_124"


@pytest.fixture(scope="module")
def study():
    sys.path.insert(0, str(SCRIPT.parent))
    return load_script("no_depth_study")


def _walk(n):
    poses = np.repeat(np.eye(4)[None], n, 0)
    poses[:, 0, 3] = 0.01 * np.arange(n)  # 1 cm a frame along x
    return poses


def test_parse_frames(study):
    assert study.parse_frames("15,25,60:63,25") == [15, 25, 60, 61, 62]


def test_gap_errors_measure_each_dropped_frame_from_the_last_frame_with_depth(study, tmp_path):
    gt = _walk(10)
    est = gt.copy()
    est[2:, 1, 3] += 0.05  # 5 cm of drift from frame 2 on: before the gaps, it does not count
    est[5, 0, 3] += 0.02  # dropped frame 5: 2 cm off along its motion
    a = math.radians(1.0)  # dropped frame 6 (second of a gap 5-6): turned 1 degree about z
    est[6, :2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    write_tum_trajectory(tmp_path / "gt.txt", np.arange(10.0), gt)
    write_tum_trajectory(tmp_path / "est.txt", np.arange(10.0), est)
    e = study.gap_errors(tmp_path / "est.txt", tmp_path / "gt.txt", [5, 6])
    assert e["per_frame_cm"] == pytest.approx([2.0, 0.0], abs=1e-6)  # both from frame 4, the last with depth
    assert e["per_frame_deg"] == pytest.approx([0.0, 1.0], abs=1e-4)


@pytest.mark.skipif(not TUM_FAST.exists(), reason="needs the shared TUM excerpt")
def test_the_copy_zeroes_the_depth_of_the_dropped_frames_only(tmp_path):
    import imageio.v3 as iio

    sys.path.insert(0, str(SCRIPT.parent))
    from induced_loss import blacked_out_copy

    dst = tmp_path / "tum_fr1_rpy_0_124"
    changed = blacked_out_copy(TUM_FAST, dst, 0, 0, frames=[3], depth_only=True)
    pairs = [ln.split() for ln in (TUM_FAST / "associations.txt").read_text().splitlines()
             if ln.strip() and not ln.startswith("#")]
    assert changed == [pairs[3][3]]  # the depth PNG of pair 3, nothing else
    assert not iio.imread(dst / pairs[3][3]).any() and iio.imread(dst / pairs[4][3]).any()
    assert np.array_equal(iio.imread(dst / pairs[3][1]), iio.imread(TUM_FAST / pairs[3][1]))
