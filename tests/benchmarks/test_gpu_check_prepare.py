"""benchmarks/gpu_check_prepare.py at toy size: the first frames of the real TUM excerpt, cut with their index files,
still load as a TUM sequence."""

from tests.benchmarks.conftest import script_on_path


def test_the_cut_excerpt_is_a_tum_sequence_of_those_frames(shared_data, tmp_path):
    with script_on_path("gpu_check_prepare") as prep:
        size = prep.cut_excerpt(shared_data / "tum_fr1_rpy", tmp_path / "cut", 3)
    from slam.data import load_dataset

    ds = load_dataset(tmp_path / "cut", kind="tum")
    assert len(ds) == 3 and size > 0
    assert len(list((tmp_path / "cut" / "rgb").iterdir())) == 3
