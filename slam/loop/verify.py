"""Is a loop candidate the same place, and where: ORB matches, RANSAC PnP on the candidate's depth, then ICP of the
two depth clouds from the PnP pose. A loop is accepted only where the two estimates agree and the surfaces fit,
with every threshold strict: a false loop bends the whole trajectory, a missed one only leaves the drift."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slam.core.pose import pose_gap
from slam.loop.features import KeyframeFeatures
from slam.loop.icp import icp


@dataclass(frozen=True)
class VerifyLimits:
    """The thresholds a loop must pass (``slam.config.LoopsConfig`` sets them)."""

    ratio: float = 0.8
    min_matches: int = 30
    min_inliers: int = 30
    min_inlier_share: float = 0.3
    reprojection_px: float = 2.0
    max_icp_rms: float = 0.01
    min_overlap: float = 0.15
    max_disagreement_m: float = 0.05
    max_disagreement_deg: float = 3.0


@dataclass(frozen=True)
class Verdict:
    """A candidate's verification: ``ok``, ``reason`` (the first test it failed, "" when accepted), ``rel``
    ``[4, 4]``: the query camera in the candidate's camera (c2w_cand^-1 c2w_query, metres) or None, and the
    evidence: ``matches``, ``inliers`` (PnP), ``icp_rms`` (metres), ``overlap`` (share of the query's cloud)."""

    ok: bool
    reason: str
    rel: np.ndarray | None = None
    matches: int = 0
    inliers: int = 0
    icp_rms: float = float("nan")
    overlap: float = 0.0

    def evidence(self) -> dict:
        """The numbers of an event (JSON-ready)."""
        return {"matches": self.matches, "inliers": self.inliers, "icp_rms_m": round(self.icp_rms, 5),
                "overlap": round(self.overlap, 3)}


def match(query: KeyframeFeatures, cand: KeyframeFeatures, ratio: float) -> np.ndarray:
    """``[P, 2]`` index pairs (query keypoint, candidate keypoint) passing Lowe's ratio test, the candidate's point
    having valid depth."""
    import cv2

    if len(query.descriptors) < 2 or len(cand.descriptors) < 2:
        return np.zeros((0, 2), int)
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(query.descriptors, cand.descriptors, k=2)
    pairs = [(m[0].queryIdx, m[0].trainIdx) for m in knn
             if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    pairs = np.array(pairs, int).reshape(-1, 2)
    return pairs[np.isfinite(cand.points[pairs[:, 1]]).all(1)] if len(pairs) else pairs


def verify(query: KeyframeFeatures, cand: KeyframeFeatures, intrinsics, limits: VerifyLimits,
           seed: int = 0) -> Verdict:
    """Verify that ``query`` sees the place ``cand`` saw (both :class:`KeyframeFeatures` of the same camera,
    ``intrinsics`` of their working image); ``seed`` makes RANSAC's draws repeatable."""
    import cv2

    pairs = match(query, cand, limits.ratio)
    if len(pairs) < limits.min_matches:
        return Verdict(False, "matches", matches=len(pairs))
    K = np.array([[intrinsics.fx, 0, intrinsics.cx], [0, intrinsics.fy, intrinsics.cy], [0, 0, 1]], np.float64)
    cv2.setRNGSeed(int(seed))
    ok, rvec, tvec, inl = cv2.solvePnPRansac(cand.points[pairs[:, 1]].astype(np.float64),
                                             query.keypoints[pairs[:, 0]].astype(np.float64), K, None,
                                             iterationsCount=300, reprojectionError=limits.reprojection_px,
                                             confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    n_in = 0 if inl is None else len(inl)
    if not ok or n_in < limits.min_inliers or n_in < limits.min_inlier_share * len(pairs):
        return Verdict(False, "inliers", matches=len(pairs), inliers=n_in)
    T_qc = np.eye(4)
    T_qc[:3, :3] = cv2.Rodrigues(rvec)[0]
    T_qc[:3, 3] = tvec.ravel()
    pnp = np.linalg.inv(T_qc)  # the query camera in the candidate's
    both = pairs[inl.ravel()]
    both = both[np.isfinite(query.points[both[:, 0]]).all(1)]
    res = icp(query.cloud, cand.cloud, cand.normals, pnp,
              anchors=(query.points[both[:, 0]].astype(np.float64), cand.points[both[:, 1]].astype(np.float64)))
    base = dict(matches=len(pairs), inliers=n_in, icp_rms=res.rms, overlap=res.overlap)
    if res.overlap < limits.min_overlap or not res.rms <= limits.max_icp_rms:
        return Verdict(False, "icp", rel=res.transform, **base)
    dt, dr = pose_gap(pnp, res.transform)
    if dt > limits.max_disagreement_m or dr > limits.max_disagreement_deg:
        return Verdict(False, "disagree", rel=res.transform, **base)
    return Verdict(True, "", rel=res.transform, **base)
