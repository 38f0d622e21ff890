"""The one reader of TUM pose rows (``timestamp tx ty tz qx qy qz qw``): the TUM loader's ground truth and every
trajectory slam.eval reads go through :func:`slam.data.tum_format.read_tum_poses`."""

import numpy as np
import pytest

from slam.data.tum_format import read_rows, read_tum_poses
from slam.errors import SlamInputError


def test_pose_rows_skip_comments_and_blank_lines_and_name_a_bad_line(tmp_path):
    p = tmp_path / "groundtruth.txt"
    p.write_text("# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n\n"
                 "1.0 0.1 0.2 0.3 0 0 0 1\n   \n2.5,0.4,0.5,0.6,0,0,0.7071068,0.7071068 extra\n  # indented comment\n")
    rows = read_tum_poses(p)
    assert rows.dtype == np.float64 and rows.shape == (2, 8)
    np.testing.assert_array_equal(rows[:, 0], [1.0, 2.5])
    np.testing.assert_array_equal(rows[1, 1:4], [0.4, 0.5, 0.6])
    assert [n for n, _ in read_rows(p)] == [4, 6]  # line numbers as in the file

    p.write_text("# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    with pytest.raises(SlamInputError, match=r"groundtruth.txt:3: expected 8 columns 'timestamp tx ty tz qx qy qz "
                                             r"qw', got 7"):
        read_tum_poses(p)
    p.write_text("1.0 0 0 0 0 0 0 1\n\n2.0 0 zero 0 0 0 0 1\n")
    with pytest.raises(SlamInputError, match=r"groundtruth.txt:3: non-numeric value"):
        read_tum_poses(p)
    p.write_text("1.0 0 0 0 0 0 0 1\n# a comment\n2.0 0 nan 0 0 0 0 1\n")
    with pytest.raises(SlamInputError, match=r"groundtruth.txt: ground-truth row 1 contains NaN or inf \(line 3, "):
        read_tum_poses(p, what="ground-truth row")
    p.write_text("1.0 0 0 0 0 0 0 2\n")
    with pytest.raises(SlamInputError, match=r"pose 0 has quaternion norm 2.0000 \(line 1\)"):
        read_tum_poses(p)
    p.write_text("# only comments\n\n")
    with pytest.raises(SlamInputError, match="groundtruth.txt: no poses"):
        read_tum_poses(p)
    with pytest.raises(SlamInputError, match="missing.txt: file not found"):
        read_tum_poses(tmp_path / "missing.txt")
