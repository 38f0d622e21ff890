"""Loop verification on real frames: the same place found with the ground truth's relative pose, another place
refused; ICP's recovery of a known motion, and the features that pin its sliding direction."""

import numpy as np
import pytest

pytest.importorskip("cv2")

from slam.loop.features import extract  # noqa: E402
from slam.loop.icp import icp  # noqa: E402
from slam.core.pose import pose_gap  # noqa: E402
from slam.loop.verify import VerifyLimits, verify  # noqa: E402


def _feat(rpy, k):
    frames, gt, intr = rpy
    return extract(k, gt[k], *frames[k], intr)


@pytest.mark.parametrize("a, b", [(0, 20), (20, 55)])
def test_verify_finds_the_ground_truth_relative_pose(rpy, a, b):
    _, gt, intr = rpy
    v = verify(_feat(rpy, b), _feat(rpy, a), intr, VerifyLimits())
    assert v.ok, v
    assert v.inliers >= 80 and v.icp_rms < 0.01
    dt, dr = pose_gap(np.linalg.inv(gt[a]) @ gt[b], v.rel)
    # fr1's colour and depth are not taken at the same instant and the camera turns fast: 3 cm and 3-4 degrees is
    # what the ground truth itself allows here
    assert dt < 0.05 and dr < 4.0, (dt, dr)


def test_verify_refuses_another_place(rpy, tiny_seq):
    from slam.data import load_dataset

    room = load_dataset(tiny_seq)
    other = extract(0, np.eye(4), np.asarray(room[10].color), np.asarray(room[10].depth), room[10].intrinsics)
    v = verify(_feat(rpy, 30), other, rpy[2], VerifyLimits())
    assert not v.ok and v.reason in ("matches", "inliers")
    flipped = _feat(rpy, 30)  # the same frame's keypoints with the descriptors of another: no consistent pose
    flipped.descriptors = _feat(rpy, 0).descriptors[: len(flipped.descriptors)]
    assert not verify(flipped, _feat(rpy, 55), rpy[2], VerifyLimits()).ok


def _corner(n=40):
    """Points on three orthogonal planes (a room corner), with normals: ICP's motion is fully constrained."""
    g = np.linspace(0.1, 1.0, n)
    a, b = [x.ravel() for x in np.meshgrid(g, g)]
    z = np.zeros_like(a)
    pts = np.concatenate([np.stack(p, 1) for p in ((a, b, z), (a, z, b), (z, a, b))]) + [0, 0, 2.0]
    nrm = np.concatenate([np.tile(v, (len(a), 1)) for v in ([0, 0, 1.0], [0, 1.0, 0], [1.0, 0, 0])])
    return pts, nrm


def _motion(rx=0.03, t=(0.04, -0.02, 0.03)):
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([rx, -0.02, 0.01]).as_matrix()
    T[:3, 3] = t
    return T


def test_icp_recovers_a_known_motion():
    tgt, nrm = _corner()
    T = _motion()
    src = (tgt - T[:3, 3]) @ T[:3, :3]  # T maps src onto tgt
    res = icp(src, tgt, nrm, np.eye(4))
    assert pose_gap(res.transform, T)[0] < 1e-3 and pose_gap(res.transform, T)[1] < 0.05
    assert res.rms < 1e-4 and res.overlap > 0.95


def test_feature_anchors_pin_what_a_plane_leaves_free():
    tgt, nrm = _corner()
    plane = slice(0, len(tgt) // 3)  # the floor alone: sliding along it costs ICP nothing
    T = _motion(rx=0.0, t=(0.05, 0.03, 0.0))
    T[:3, :3] = np.eye(3)
    src = tgt[plane] - T[:3, 3]
    free = icp(src, tgt[plane], nrm[plane], np.eye(4))
    assert pose_gap(free.transform, T)[0] > 0.02  # slid: the residual is zero anyway
    anchors = (src[::50], tgt[plane][::50])
    pinned = icp(src, tgt[plane], nrm[plane], np.eye(4), anchors=anchors)
    assert pose_gap(pinned.transform, T)[0] < 1e-3
