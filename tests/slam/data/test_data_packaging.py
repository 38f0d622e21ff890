import __future__
import importlib
import types

import pytest

FACES = ["slam.data", "slam.eval", "slam.data.synthetic"]


def _public_bindings(mod) -> set[str]:
    """Names a reader of the module sees as its API: public, and not a submodule or a __future__ flag."""
    return {name for name, value in vars(mod).items() if not name.startswith("_")
            and not isinstance(value, (types.ModuleType, __future__._Feature))}


@pytest.mark.parametrize("module", FACES)
def test_public_names_import(module):
    """``__all__`` lists exactly the public names the package face binds, once each, and every class or function
    in it is defined inside slam (a face re-exports its own package, not a third-party name)."""
    mod = importlib.import_module(module)
    assert len(mod.__all__) == len(set(mod.__all__)), "duplicates in __all__"
    assert sorted(mod.__all__) == sorted(_public_bindings(mod))
    namespace: dict = {}
    exec(f"from {module} import *", namespace)
    assert sorted(k for k in namespace if k != "__builtins__") == sorted(mod.__all__)
    for name in mod.__all__:
        obj = getattr(mod, name)
        if isinstance(obj, (type, types.FunctionType)):
            assert obj.__module__.startswith("slam."), f"{module}.{name} comes from {obj.__module__}"


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
