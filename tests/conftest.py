import os
from pathlib import Path

import pytest

# Triton decides at import whether its own library functions (tl.sum...) are interpreted, so the choice is made
# here, before anything imports it: without a GPU the Triton kernel tests run in the interpreter on CPU tensors.
# Set TRITON_INTERPRET=0 on a CUDA machine to test the compiled kernels instead.
if "TRITON_INTERPRET" not in os.environ:
    import torch

    if not torch.cuda.is_available():
        os.environ["TRITON_INTERPRET"] = "1"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Root of the shared datasets: $LRSLAM_SHARED_DATA, default <repo>/../shared/data; skips if missing."""
    root = Path(os.environ.get("LRSLAM_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    if not root.is_dir():
        pytest.skip(f"shared data not found at {root} (set LRSLAM_SHARED_DATA)")
    return root
