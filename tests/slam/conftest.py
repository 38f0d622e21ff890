import pytest

# a few-second SLAM run on the tiny sequence: every stage runs, nothing converges
TINY = ["data.max_frames=6", "tracking.iters=3", "tracking.pixels=100", "mapping.iters=3",
        "mapping.iters_first=5", "mapping.pixels=200", "rendering.n_stratified=8", "rendering.n_importance=4"]


@pytest.fixture(scope="session")
def tiny_seq(tmp_path_factory):
    """A 24-frame 60x80 synthetic sequence on disk (Replica layout)."""
    from slam.data.synthetic import SynthConfig, generate

    out = tmp_path_factory.mktemp("tiny_synth")
    generate(out, SynthConfig(frames=24, height=60, width=80, supersample=1))
    return out
