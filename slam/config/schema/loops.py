"""The ``loops`` section: loop closure (docs/loops.md)."""

from __future__ import annotations

from dataclasses import dataclass

from slam.config.declare import COUNT, FRACTION, METRES, NONNEG, POSITIVE, key, num


@dataclass
class LoopsConfig:
    """(ours; ESLAM and the LRSLAM paper have none) Place recognition over loop keyframes, verification, a pose graph
    over them, and the corrected trajectory written as `trajectory.txt` (the tracker's as
    `trajectory_odometry.txt`)."""

    enabled: bool = key(False, "detect loops beside the tracker and correct the trajectory by a pose graph at the end "
                               "(needs the `loops` extra: OpenCV and gtsam)")
    keyframe_distance: float = num(0.3, **METRES, doc="a trusted frame with depth becomes a loop keyframe once the "
                                                      "camera moved this far (metres) since the last one")
    keyframe_angle: float = num(15.0, lo=0, lo_open=True, hi=180, doc=(
        "... or turned this many degrees since the last one"))
    features: int = num(500, lo=10, hi=100_000, doc="ORB keypoints per loop keyframe (OpenCV), where there is depth")
    words: int = num(128, lo=2, hi=100_000, doc="words of the vocabulary learned from the first keyframes' "
                                               "descriptors (k-means, no pretrained vocabulary)")
    vocabulary_after: int = num(10, lo=1, hi=100_000, doc="loop keyframes whose descriptors the vocabulary is "
                                                          "learned from; appearance candidates start after them")
    min_gap_frames: int = num(150, **NONNEG, doc="frames between a keyframe and a loop candidate at least: nearer "
                                                 "ones are the tracker's own neighbours")
    candidates: int = num(3, lo=1, hi=100, doc="candidates verified per keyframe from appearance (best word "
                                               "histograms), and as many from geometry (nearest poses)")
    shortlist: int = num(10, lo=1, hi=1000, doc="keyframes the word histograms shortlist; their feature matches "
                                                "pick the `candidates` to verify")
    search_radius: float = num(1.0, **METRES, doc="geometric candidates lie within this distance (metres) of the "
                                                  "keyframe's pose, plus `drift_per_metre` of the path between them")
    drift_per_metre: float = num(0.05, **NONNEG, doc="the drift bound's growth per metre travelled")
    min_inliers: int = num(30, **COUNT, doc="RANSAC PnP inliers a loop needs at least")
    min_inlier_share: float = num(0.3, **FRACTION, doc="... and this share of the feature matches")
    reprojection_px: float = num(2.0, **POSITIVE, doc="RANSAC PnP inlier threshold in working-image pixels")
    max_icp_rms: float = num(0.01, **METRES, doc="point-to-plane ICP residual (metres) a loop's depth clouds may "
                                                 "keep at most")
    min_overlap: float = num(0.15, **FRACTION, doc="share of the keyframe's depth cloud ICP must pair at least")
    max_disagreement_m: float = num(0.05, **METRES, doc="PnP and ICP relative poses may differ by at most this "
                                                        "translation (metres) ...")
    max_disagreement_deg: float = num(3.0, lo=0, lo_open=True, hi=180, doc="... and this rotation (degrees)")
    untrusted_scale: float = num(100.0, lo=1, hi=1e6, doc=(
        "odometry edges over a frame the tracking guard did not trust get sigmas this many times larger: the graph "
        "puts the correction where the tracker slipped"))
    refine_iters: int = num(500, lo=0, hi=1_000_000, doc=(
        "after a run whose loops corrected the trajectory: the keyframes move with the correction and the fields are "
        "re-fitted on them, poses fixed, for this many mapping iterations (0: the map stays in the tracker's frame)"))
