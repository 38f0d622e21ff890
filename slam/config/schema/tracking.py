"""The ``tracking`` section: each frame's camera pose against the map, the checks on it and the recovery."""

from __future__ import annotations

from dataclasses import dataclass

from slam.config.declare import BIG, COUNT, FRACTION, NONNEG, POSITIVE, RATE, choice, key, num
from slam.config.schema.weights import TRACKING_WEIGHTS
from slam.core.losses import LossWeights

_GUARD = "(ours) a result is implausible (re-tracked by `recovery`, not mapped) when"


@dataclass
class TrackingConfig:
    """The camera pose of each frame: ESLAM's Adam tracker or Gauss-Newton (ours), its starting pose, the checks
    on its result (ours, slam.engine.tracking_guard) and the recovery of a lost camera (ours,
    slam.engine.recovery)."""

    iters: int = num(8, **COUNT, doc="Adam iterations per frame (a cap with `patience`)")
    pixels: int = num(2000, lo=10, hi=BIG, doc="pixels drawn per Adam iteration, or per Gauss-Newton round")
    lr_t: float = num(0.001, **RATE, doc="Adam learning rate of the camera translation")
    lr_r: float = num(0.001, **RATE, doc="Adam learning rate of the camera rotation (a quaternion)")
    ignore_edge: list = num(lambda: [75, 75], **NONNEG, doc=(
        "`[rows, columns]` of the working image's border no tracking pixel is drawn from"))
    init: str = choice("const_speed", ("const_speed", "previous", "icp"), doc=(
        "the starting pose: ESLAM's constant velocity, the `previous` pose, or `icp` (ours): depth ICP from the "
        "previous frame started at the constant-velocity guess (slam/core/odometry.py)"))
    icp_hold: float = num(3e-4, lo=0, hi=1.0, doc=(
        "(ours) with `init: icp`: the start keeps the previous pose, not the constant-velocity guess, in the "
        "directions the depth does not observe (a single plane in view): those whose point-to-plane eigenvalue is "
        "below this times the largest; 0: off"))
    icp_normals: int = num(3, lo=1, hi=15, doc=(
        "(ours) depth ICP's normals (the `init: icp` start, relocalisation) averaged over this many pixels square, "
        "an odd number (1: central differences alone, as before). Raw normals of far, noisy depth held the start "
        "back along the optical axis in a corridor (docs/robustness.md, \"Depth ICP's normals\")"))
    icp_wide: float = num(0.6, lo=0, hi=1.0, doc=(
        "(ours) with `init: icp`: a registration from the constant-velocity guess that matches fewer than this share "
        "of the frame's points is tried again from the guess turned 8 degrees about each camera axis and from the "
        "previous pose, and the one matching the most points kept (docs/robustness.md, \"How far apart the frames "
        "can be\"); 0: off"))
    outlier_factor: float = num(10.0, **POSITIVE, doc=(
        "a ray is an outlier when its depth error is over this times the median error (ESLAM's rule)"))
    patience: int = num(0, **NONNEG, doc=(
        "(ours) stop once this many iterations found no loss below the best by `min_improvement`; 0: ESLAM's fixed "
        "`iters`"))
    min_iters: int = num(1, **COUNT, doc="(ours) with `patience`: iterations a call runs before it may stop")
    min_improvement: float = num(0.0, lo=0, hi=1, hi_open=True, doc=(
        "(ours) with `patience`: the relative decrease of the best loss that counts as better"))
    lost_loss_factor: float = num(4.0, **NONNEG, doc=f"{_GUARD} its loss is over this times the recent median; 0: "
                                                     "no such check")
    lost_min_inliers: float = num(0.5, **FRACTION, doc=f"{_GUARD} fewer than this share of its rays are inliers; 0: "
                                                       "no such check")
    max_speed: float = num(3.0, lo=0, hi=1000.0, doc=f"{_GUARD} the camera moved faster than this (m/s); 0: no such "
                                                     "check")
    max_angular_speed: float = num(360.0, lo=0, hi=100000.0, doc=f"{_GUARD} the camera turned faster than this "
                                                                 "(deg/s); 0: no such check")
    recovery: bool = key(True, "(ours) track an implausible result again from several starts with twice the budget, "
                               "keeping the best plausible one (false: the frame is lost, its pose the prediction)")
    recovery_optimizer: str = choice("same", ("same", "adam"), doc=(
        "(ours) the optimiser of the recovery attempts: the tracker's own, or `adam` (with `optimizer: gauss_newton`: "
        "a first-order retry where the second-order step failed, as at a fast turn into a wall)"))
    realtime_recovery_optimizer: str = choice("same", ("same", "adam"), doc=(
        "(ours) `recovery_optimizer` of a real-time run (`data.realtime`, a live camera): a camera does not wait, and "
        "an Adam retry at twice the budget held a real-time fr1_rpy run 1.8-2.0 s, the next frame taken 20+ frames "
        "on"))
    relocalize_after: int = num(5, lo=0, hi=BIG, doc=(
        "(ours) after this many frames in a row without a trusted pose (lost, unreadable or without depth), "
        "relocalise against the keyframes nearest the last trusted pose (slam/engine/recovery.py); 0: never"))
    relocalize_keyframes: int = num(3, lo=1, hi=100, doc="(ours) how many keyframes relocalisation tries")
    without_depth: str = choice("color", ("color", "predict"), doc=(
        "(ours) a frame without valid depth is tracked on its `color` against the map's rendered depth, or keeps the "
        "motion model's prediction (`predict`); either way it is not mapped"))
    weights: LossWeights = key(TRACKING_WEIGHTS, "the tracking loss's weight of each term (ESLAM's)")
    optimizer: str = choice("adam", ("adam", "gauss_newton"), doc=(
        "(ours) `adam`: ESLAM's tracker (`iters`, `lr_*`, `patience`); `gauss_newton`: Levenberg-Marquardt on one set "
        "of pixels per round (`gn_*`; slam/engine/gauss_newton.py)"))
    gn_iters: int = num(10, lo=2, hi=1000, doc="(ours) Gauss-Newton: at most this many loss evaluations a round")
    gn_damping: float = num(1e-3, lo=0, hi=1e6, doc="(ours) Gauss-Newton: the Levenberg-Marquardt damping it starts "
                                                    "from")
    gn_step_m: float = num(1e-4, lo=0, hi=1.0, doc=(
        "(ours) Gauss-Newton: converged once a step moves the camera less than this (metres) and turns it less than "
        "`gn_step_deg`"))
    gn_step_deg: float = num(0.01, lo=0, hi=90.0, doc="(ours) Gauss-Newton: the rotation (degrees) of a converged "
                                                      "step (with `gn_step_m`)")
    gn_min_decrease: float = num(0.0, lo=0, hi=1.0, doc=(
        "(ours) Gauss-Newton: a step whose predicted loss decrease (the normal equations' quadratic model) is under "
        "this share of the loss ends the round, its pose evaluated for the loss alone: a next step would lower it by a "
        "fraction of that again; 0: the round ends only by `gn_step_m` / `gn_step_deg` or `gn_iters`"))
    gn_rounds: int = num(1, lo=1, hi=100, doc=(
        "(ours) Gauss-Newton rounds: each later one draws fresh pixels and redoes the outlier rule at the pose the "
        "previous one reached"))
    gn_hessian: str = choice("every", ("every", "first"), doc=(
        "(ours) Gauss-Newton: `every` evaluation brings the full normal equations; `first`: only a round's first, "
        "later ones the gradient alone (one backward pass) with that H kept"))
    gn_prior: float = num(0.0, lo=0, hi=1e6, doc=(
        "(ours) Gauss-Newton: a prior towards the start pose, this (kappa) times the mean curvature of the rotation / "
        "translation axes, the same on every axis of each; 0: none"))
    gn_prior_shape: str = choice("camera", ("camera", "world", "geometry"), doc=(
        "(ours) Gauss-Newton: the prior's metric; `camera`: the same on each of the camera's own rotation and "
        "translation axes; `world`: the same on each axis of the solver's tangent, rotations about the world's "
        "origin (a camera far from it has its rotations held by their lever arm); `geometry`: as firmly as the "
        "frame's depth holds each direction (its point-to-plane normal matrix), scaled to `camera`'s mean"))
