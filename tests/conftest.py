import os
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Root of the shared datasets: $LRSLAM_SHARED_DATA, default <repo>/../shared/data; skips if missing."""
    root = Path(os.environ.get("LRSLAM_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    if not root.is_dir():
        pytest.skip(f"shared data not found at {root} (set LRSLAM_SHARED_DATA)")
    return root
