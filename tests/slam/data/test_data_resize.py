"""The working image: its size from the camera's focal length, and the crop counted on the raw image."""

import pytest

from slam.data import Intrinsics
from slam.data.resize import resize_and_crop, working_size
from slam.errors import SlamInputError
from tests.slam.config.test_profiles import RAW


def test_the_working_resolution_follows_the_focal_length():
    assert working_size(RAW["tum"], 207) == (192, 256)        # the TUM budget's size
    assert working_size(RAW["7scenes"], 207) == (168, 224)
    assert working_size(RAW["replica"], 207) == (232, 416)
    assert working_size(RAW["synthetic"], 207) == (120, 160)  # never up
    assert resize_and_crop(RAW["synthetic"], focal_px=207) == (None, 0)
    assert working_size(Intrinsics(48.0, 48.0, 39.5, 29.5, 60, 80), 207) == (60, 80)  # not rounded up to 64
    assert resize_and_crop(RAW["tum"], focal_px=207, crop_edge_raw=10) == ((192, 256), 4)
    assert resize_and_crop(RAW["tum"], crop_size=(384, 512), crop_edge_raw=10) == ((384, 512), 8)  # ESLAM's 8
    assert resize_and_crop(RAW["tum"], crop_size=(96, 128), crop_edge=2, focal_px=207) == ((96, 128), 2)  # given wins
    for bad in (0, -5.0, float("nan")):
        with pytest.raises(SlamInputError, match="focal_px"):
            working_size(RAW["tum"], bad)
