import numpy as np
import pytest


@pytest.fixture(scope="module")
def rpy(shared_data):
    """fr1_rpy (real TUM RGB-D, the camera turning in place over a desk) at a 160 x 120 working size, as the loop
    closer sees frames: ``(frames, ground-truth poses, intrinsics)`` for the first 60 frames."""
    from slam.data import load_dataset

    path = shared_data / "tum_fr1_rpy"
    if not path.is_dir():
        pytest.skip("tum_fr1_rpy excerpt missing")
    ds = load_dataset(path, "tum", crop_size=[120, 160], max_frames=60)
    frames = [(np.asarray(ds[i].color, np.float32), np.asarray(ds[i].depth, np.float32)) for i in range(len(ds))]
    return frames, np.asarray(ds.gt_poses, np.float64), ds[0].intrinsics
