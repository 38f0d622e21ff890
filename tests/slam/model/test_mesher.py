import numpy as np
import pytest

from slam.model.mesher import Hull


def _inside(hull: Hull, points: np.ndarray) -> np.ndarray:
    """The point-wise half-space test (the definition in Hull's docstring): the oracle for the per-line intervals."""
    n, d = hull.equations[:, :3], hull.equations[:, 3]
    p = hull.centroid + (points - hull.centroid) / hull.scale
    return (p @ n.T + d <= 1e-9).all(1)


def _in_intervals(hull: Hull, xs, ys, zs) -> np.ndarray:
    lo, hi = hull.x_intervals(ys, zs)
    x = np.asarray(xs)[:, None, None]
    return (lo[None] <= x) & (x <= hi[None])


@pytest.mark.parametrize("shape", ["blob", "box"])
def test_grid_line_intervals_equal_the_point_test(shape):
    """The per-line intervals give exactly the per-point half-space test, including facets parallel to x
    (a box hull: normals with n_x = 0) and lines that miss the hull."""
    rng = np.random.default_rng(0)
    if shape == "blob":
        pts = rng.normal(size=(800, 3)) * [2.0, 1.0, 0.7] + [0.3, -0.2, 1.0]
    else:
        corners = np.array([[x, y, z] for x in (-1.0, 2.0) for y in (-0.5, 1.5) for z in (0.0, 3.0)])
        pts = np.concatenate([corners, rng.uniform([-1, -0.5, 0], [2, 1.5, 3], size=(200, 3))])
    hull = Hull(pts, scale=1.02)
    xs, ys, zs = np.linspace(-7, 7, 61), np.linspace(-4, 4, 47), np.linspace(-2, 4.5, 53)
    grid = _in_intervals(hull, xs, ys, zs)
    ref = _inside(hull, np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), -1).reshape(-1, 3)).reshape(grid.shape)
    assert grid.shape == (61, 47, 53)
    assert 0 < ref.sum() < ref.size
    assert np.array_equal(grid, ref)


def test_degenerate_hull_contains_everything():
    hull = Hull(np.zeros((5, 3)))  # qhull fails: no hull, no culling
    assert hull.equations is None
    assert _in_intervals(hull, np.arange(3.0), np.arange(2.0), np.arange(4.0)).all()
