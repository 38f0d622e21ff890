import importlib

import pytest


@pytest.mark.parametrize("module", ["slam.data", "slam.eval", "slam.data.synthetic"])
def test_public_names_import(module):
    mod = importlib.import_module(module)
    for name in mod.__all__:
        assert getattr(mod, name) is not None, f"{module}.{name}"


def test_contract_names():
    from slam.data import Frame, Intrinsics, load_dataset  # noqa: F401
    from slam.data.synthetic import SynthConfig, default_sequence, generate  # noqa: F401
    from slam.eval import (  # noqa: F401
        ate, associate, cull_mesh, depth_l1, plot_trajectory, read_tum_trajectory, reconstruction_metrics,
        write_tum_trajectory,
    )

    k = Intrinsics(100.0, 100.0, 50.0, 40.0, 80, 100)
    assert k.K.shape == (3, 3) and k.scaled(0.5, 0.5).width == 50 and k.cropped(5).cx == 45.0
    cfg = SynthConfig()
    assert (cfg.seed, cfg.frames, cfg.height, cfg.width, cfg.depth_noise_sigma, cfg.sensor_holes) == (0, 120, 120, 160, 0.0, False)
