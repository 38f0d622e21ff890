"""Trajectory plots (PNG)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_trajectory"]

_AXES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


def plot_trajectory(est, gt, path, align: str = "rigid", plane: str = "auto", title: str | None = None) -> Path:
    """Top-down plot of an estimated vs ground-truth trajectory, the estimate coloured by ATE error.

    Args:
        est, gt: paired ``[N, 3]`` positions or ``[N, 4, 4]`` camera-to-world poses (numpy or torch), metres.
        path: output PNG.
        align: alignment before plotting (:func:`slam.eval.ate`): ``"rigid"``, ``"sim3"`` or ``"none"``.
        plane: ``"xy"``, ``"xz"``, ``"yz"`` or ``"auto"`` (the two axes along which the ground truth spreads
            most: top-down for a z-up world, x-z for a TUM-style first-camera frame).
    Returns the written path.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    from slam.eval.ate import ate

    res = ate(est, gt, align=align)
    e, g, err = res.aligned, res.gt, res.errors
    if plane == "auto":
        spread = g.max(0) - g.min(0)
        a, b = sorted(np.argsort(spread)[-2:])
    else:
        a, b = _AXES[plane]
    names = "xyz"
    fig, ax = plt.subplots(figsize=(6.4, 5.6), dpi=110)
    ax.plot(g[:, a], g[:, b], color="0.35", lw=1.5, ls="--", label="ground truth")
    seg = np.stack([e[:-1][:, [a, b]], e[1:][:, [a, b]]], axis=1)
    cmap = plt.get_cmap("plasma")
    lc = LineCollection(seg, cmap=cmap, linewidths=2.2)
    lc.set_array(0.5 * (err[:-1] + err[1:]) * 100.0)
    ax.add_collection(lc)
    if len(e) == 1:
        ax.scatter(e[:, a], e[:, b], c=err * 100, cmap=cmap)
    ax.plot(g[0, a], g[0, b], "o", color="green", ms=6, label="start")
    cb = fig.colorbar(lc, ax=ax, fraction=0.046, pad=0.04)
    cb.set_label("ATE (cm)")
    ax.set_xlabel(f"{names[a]} (m)")
    ax.set_ylabel(f"{names[b]} (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title or f"ATE RMSE {res.rmse * 100:.2f} cm over {res.n} frames ({align} alignment)", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
