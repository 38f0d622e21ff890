"""Absolute trajectory error (ATE) with Horn/Umeyama alignment.

Same definition as the TUM benchmark script, ESLAM's ``eval_ate.py`` and ``evo_ape --align``: align the
estimated camera centres to the ground-truth ones with a closed-form rigid (or similarity) transform, then
take statistics of the per-frame Euclidean translation error in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slam.errors import SlamInputError

__all__ = ["ATEResult", "ate", "umeyama"]


@dataclass
class ATEResult:
    """ATE statistics in metres over the ``n`` frames used (frames with a non-finite pose are dropped).

    ``errors [n]`` per-frame translation errors; ``aligned [n, 3]`` the aligned estimated positions;
    ``gt [n, 3]`` the matching ground-truth positions; ``transform [4, 4]`` maps estimate to GT
    (``x_gt ~ s R x + t``, with ``s`` = ``scale`` in the rotation block); ``used [N]`` mask of frames kept.
    """

    rmse: float
    mean: float
    median: float
    std: float
    max: float
    min: float
    errors: np.ndarray
    aligned: np.ndarray
    gt: np.ndarray
    transform: np.ndarray
    scale: float = 1.0
    used: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    @property
    def n(self) -> int:
        return int(len(self.errors))

    def as_dict(self) -> dict[str, float]:
        """The scalar statistics with the CLI's JSON keys (metres)."""
        return {
            "ate_rmse_m": self.rmse,
            "ate_mean_m": self.mean,
            "ate_median_m": self.median,
            "ate_std_m": self.std,
            "ate_max_m": self.max,
            "ate_min_m": self.min,
            "ate_frames": self.n,
            "ate_scale": self.scale,
        }


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares ``dst ~ s R src + t`` for ``[N, 3]`` point sets (Umeyama 1991, det-sign fixed).

    Returns ``(R [3, 3], t [3], s)``; ``s`` is 1 unless ``with_scale``.
    """
    mu_s = src.mean(axis=0)
    mu_d = dst.mean(axis=0)
    xs = src - mu_s
    xd = dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sgn = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sgn[2, 2] = -1.0
    r = u @ sgn @ vt
    s = 1.0
    if with_scale:
        var_s = (xs**2).sum() / len(src)
        s = float(np.trace(np.diag(d) @ sgn) / var_s) if var_s > 0 else 1.0
    t = mu_d - s * r @ mu_s
    return r, t, s


def _positions(x, name: str) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 3 and x.shape[1:] == (4, 4) or x.ndim == 3 and x.shape[1:] == (3, 4):
        return x[:, :3, 3]
    if x.ndim == 2 and x.shape[1] == 3:
        return x
    raise SlamInputError(f"ate: {name} must be [N, 3] positions or [N, 4, 4] poses, got shape {tuple(x.shape)}")


def ate(est, gt, align: str = "rigid") -> ATEResult:
    """Absolute trajectory error between paired trajectories.

    Args:
        est: estimated trajectory, ``[N, 3]`` camera centres or ``[N, 4, 4]`` camera-to-world poses
            (numpy or torch), metres.
        gt: ground truth, same pairing (row ``i`` of both is the same frame).
        align: ``"rigid"`` (rotation + translation, the reference protocol), ``"sim3"`` (+ scale, for
            monocular-style comparisons) or ``"none"``.

    Frames where either pose is non-finite (e.g. ScanNet's invalid GT) are dropped before alignment.
    Raises :class:`SlamInputError` if the lengths differ or fewer than 3 frames remain for alignment.
    """
    e = _positions(est, "est")
    g = _positions(gt, "gt")
    if len(e) != len(g):
        raise SlamInputError(f"ate: {len(e)} estimated poses but {len(g)} ground-truth poses")
    if align not in ("rigid", "sim3", "none"):
        raise SlamInputError(f"ate: align must be 'rigid', 'sim3' or 'none', got {align!r}")
    used = np.isfinite(e).all(axis=1) & np.isfinite(g).all(axis=1)
    e, g = e[used], g[used]
    need = 1 if align == "none" else 3
    if len(e) < need:
        raise SlamInputError(f"ate: need at least {need} frames with finite poses, got {len(e)}")
    transform = np.eye(4)
    scale = 1.0
    if align != "none":
        r, t, scale = umeyama(e, g, with_scale=(align == "sim3"))
        transform[:3, :3] = scale * r
        transform[:3, 3] = t
    aligned = e @ transform[:3, :3].T + transform[:3, 3]
    err = np.linalg.norm(aligned - g, axis=1)
    return ATEResult(
        rmse=float(np.sqrt(np.mean(err**2))),
        mean=float(np.mean(err)),
        median=float(np.median(err)),
        std=float(np.std(err)),
        max=float(np.max(err)),
        min=float(np.min(err)),
        errors=err,
        aligned=aligned,
        gt=g,
        transform=transform,
        scale=float(scale),
        used=used,
    )


def ate_from_files(est_path, gt_path, align: str = "rigid", max_dt: float = 0.02) -> tuple[ATEResult, np.ndarray]:
    """ATE between two TUM trajectory files, poses paired by timestamp (:func:`associate`, ``max_dt`` s).

    Returns ``(result, timestamps [M])`` where the timestamps are the estimate's paired stamps.
    Raises :class:`SlamInputError` naming both files if no timestamps pair up.
    """
    from slam.eval.trajectory import associate, read_tum_trajectory

    ts_e, pe = read_tum_trajectory(est_path)
    ts_g, pg = read_tum_trajectory(gt_path)
    ie, ig = associate(ts_e, ts_g, max_dt=max_dt)
    if len(ie) == 0:
        raise SlamInputError(
            f"{est_path}: no timestamp matches {gt_path} within {max_dt} s "
            f"(estimate spans {ts_e[0]:.3f}..{ts_e[-1]:.3f}, ground truth {ts_g[0]:.3f}..{ts_g[-1]:.3f})"
        )
    return ate(pe[ie], pg[ig], align=align), ts_e[ie]
