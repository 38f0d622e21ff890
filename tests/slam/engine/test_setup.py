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


# ------------------------------------------------------------------------------------------------- data.options
def test_an_unknown_data_option_names_the_key_and_the_dataset_kinds_options(tmp_path):
    """20b7b9c handed it to the loader, which failed as "cannot be read as replica data: ... unexpected keyword
    argument" for a synthetic preset; now it is refused before any folder is read or sequence generated."""
    from slam.config import load_config
    from slam.engine.setup import load_data
    from slam.errors import SlamInputError

    with pytest.raises(SlamInputError) as e:
        load_data(load_config("synthetic/walk", ["data.options.sede=11"], profile="quality"))
    msg = str(e.value)
    assert "config key 'data.options.sede' is not an option of synthetic data" in msg and "\n" not in msg
    assert "seed" in msg and "crop_edge" in msg and "scene" in msg
    with pytest.raises(SlamInputError, match="'data.options.seed' is not an option of tum data; it takes .*association"):
        load_data(load_config("tum/fr1_desk", [f"data.path={tmp_path / 'not read'}", "data.options.seed=1"], profile="paper"))


def test_generator_options_need_the_generated_sequence_and_the_right_type(tiny_seq):
    import dataclasses

    from slam.config import load_config
    from slam.data.synthetic import SynthConfig
    from slam.engine.setup import GENERATOR_OPTIONS, load_data
    from slam.errors import SlamInputError

    assert {f.name for f in dataclasses.fields(SynthConfig)} == {"scene", *GENERATOR_OPTIONS}  # lrslam synth's

    with pytest.raises(SlamInputError, match=r"'data.options.seed' sets how the synthetic sequence is generated: it "
                                             r"does not apply to a data folder \(data.path = "):
        load_data(load_config("synthetic", [f"data.path={tiny_seq}", "data.options.seed=11"], profile="quality"))
    with pytest.raises(SlamInputError, match="'data.options.seed' = 'eleven' must be an integer"):
        load_data(load_config("synthetic", ["data.options.seed=eleven"], profile="quality"))
    with pytest.raises(SlamInputError, match="'data.options.depth_noise_sigma' = true must be a number"):
        load_data(load_config("synthetic", ["data.options.depth_noise_sigma=true"], profile="quality"))


def test_a_synthetic_presets_generator_options_make_and_use_that_variant(tmp_path, monkeypatch):
    """``data.options.seed=11`` on a synthetic preset generates (once, into the cache) and reads the sequence of
    seed 11, as ``lrslam synth --seed 11`` writes it."""
    import json

    import torch

    from slam.config import load_config
    from slam.engine.setup import load_data

    monkeypatch.setenv("LRSLAM_CACHE", str(tmp_path))
    small = ["data.options.frames=2", "data.options.height=24", "data.options.width=32",
             "data.options.supersample=1"]
    a = load_data(load_config("synthetic", [*small, "data.options.seed=11"], profile="quality"))
    b = load_data(load_config("synthetic", small, profile="quality"))
    assert json.loads((a.root / "synth.json").read_text())["config"]["seed"] == 11
    assert len(a) == 2 and a.intrinsics.height == 24 and a.root != b.root
    assert not torch.equal(torch.as_tensor(a[0].color), torch.as_tensor(b[0].color))  # other textures
    walk = load_data(load_config("synthetic/walk", ["data.max_frames=2", "data.options.seed=11",
                                                    "data.options.height=24", "data.options.width=32"], profile="quality"))
    record = json.loads((walk.root / "synth.json").read_text())["config"]
    assert record["scene"] == "walk" and record["seed"] == 11 and record["frames"] == 2 and record["sensor_holes"]
