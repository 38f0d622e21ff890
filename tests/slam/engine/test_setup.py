"""Setting a run up: the data's fingerprint a resumed run must match."""

import shutil

import pytest


@pytest.fixture
def data(tiny_seq, tmp_path):
    d = tmp_path / "data"
    shutil.copytree(tiny_seq, d)
    return d


def _open(path):
    from slam.data import load_dataset

    return load_dataset(path)


def test_the_fingerprint_covers_every_selected_frames_names_and_sizes(data, tiny_seq):
    from slam.engine.setup import data_fingerprint, fingerprint_mismatch, fingerprints_match

    indices = list(range(0, 24, 2))
    fp = data_fingerprint(_open(data), indices)
    assert fingerprints_match(fp, _open(data), indices)
    results = data / "results"
    shutil.copyfile(results / "frame000001.png", results / "frame000010.png")  # a selected frame replaced
    assert "file sizes of the selected frames differ" in fingerprint_mismatch(fp, _open(data), indices)
    shutil.copyfile(tiny_seq / "results" / "frame000010.png", results / "frame000010.png")
    for kind in ("frame", "depth"):
        (results / f"{kind}000001.png").rename(results / f"{kind}1.png")  # not a selected frame
    assert fingerprints_match(fp, _open(data), indices)
    for kind in ("frame", "depth"):
        (results / f"{kind}000004.png").rename(results / f"{kind}4.png")  # a selected one, in the same place
    assert "file names of the selected frames differ" in fingerprint_mismatch(fp, _open(data), indices)
    assert not fingerprints_match(fp, _open(data), indices[:-1])


def test_a_fingerprint_of_the_old_form_is_compared_as_it_was(data):
    """Checkpoints written by 20b7b9c hold frame counts and the first and last file names only: they stay
    resumable (compared on what they hold) and still refuse other data they can tell apart."""
    from slam.engine.setup import fingerprints_match

    indices = list(range(6))
    old = {"frames": 6, "dataset_frames": 24,
           "files": ["frame000000.png", "frame000005.png", "depth000000.png", "depth000005.png"]}
    assert fingerprints_match(old, _open(data), indices)
    results = data / "results"
    shutil.copyfile(results / "depth000001.png", results / "depth000003.png")
    assert fingerprints_match(old, _open(data), indices)  # what the old form cannot see
    assert not fingerprints_match(old, _open(data), list(range(5)))
    assert not fingerprints_match({**old, "dataset_frames": 23}, _open(data), indices)
