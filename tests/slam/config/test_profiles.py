"""Profiles (slam/configs/profiles/) and the data presets: every preset of 20b7b9c is reproduced by a data preset and
a profile (its old name, where it named a budget, as an alias), and the working resolution follows the rule."""

import json
from pathlib import Path

import pytest

from slam.config import config_from_dict, load_config
from slam.config.dotted import flatten
from slam.config.profiles import ALIASES, PROFILES, default_profile, describe
from slam.data import Intrinsics
from slam.data.resize import resize_and_crop
from slam.errors import SlamInputError

#: ``load_config(name).to_dict()`` of every bundled preset at 20b7b9c (written there)
OLD = json.loads((Path(__file__).parent / "presets_20b7b9c.json").read_text())
#: each old name -> (preset, profile) that gives its settings today (None: an alias names its own)
NOW = {"synthetic": ("synthetic", "quality"), "synthetic/walk": ("synthetic/walk", "quality"),
       "7scenes": ("7scenes", "quality"), "tum": ("tum", "paper"), "tum/fr1_rpy": ("tum/fr1_rpy", "paper"),
       "tum/fr1_desk": ("tum/fr1_desk", "paper"), "replica": ("replica", "paper"),
       "replica/room0": ("replica/room0", "paper"), "scannet": ("scannet", "paper"),
       "scannet/scene0000": ("scannet/scene0000", "paper"), **{name: (name, None) for name in ALIASES}}
#: keys a profile has changed since 20b7b9c on purpose: Adam retries of the Gauss-Newton tracker (the walk's far turn,
#: measured in a0137aa's message), tracking with the mapping's loss weights, mapping with ESLAM's tracking tail weight
#: (both docs/robustness.md)
CHANGED_SINCE = {"realtime": ("tracking.recovery_optimizer", "tracking.weights", "mapping.weights")}
#: a raw camera of each dataset kind (the sizes and focal lengths of its sensor)
RAW = {"tum": Intrinsics(517.3, 516.5, 318.6, 255.3, 480, 640), "7scenes": Intrinsics(585.0, 585.0, 320.0, 240.0, 480, 640),
       "scannet": Intrinsics(577.6, 578.7, 318.9, 242.7, 480, 640), "replica": Intrinsics(600.0, 600.0, 599.5, 339.5, 680, 1200),
       "synthetic": Intrinsics(96.0, 96.0, 79.5, 59.5, 120, 160)}


def _camera(options: dict, kind: str):
    keys = ("crop_size", "crop_edge", "crop_edge_raw", "focal_px")
    return resize_and_crop(RAW[kind], **{k: options.get(k) for k in keys})


def test_every_old_preset_is_a_data_preset_and_a_profile():
    assert set(NOW) == set(OLD)
    for old_name, (preset, profile) in NOW.items():
        old, new = OLD[old_name], load_config(preset, profile=profile).to_dict()
        assert new["profile"] == (profile or ALIASES[old_name].profile)
        kind = old["data"]["kind"]
        assert _camera(old["data"]["options"], kind) == _camera(new["data"]["options"], kind), old_name
        a, b = flatten(config_from_dict(old).to_dict()), flatten(new)  # as a resume reads the old: keys added since at their defaults
        inert = ("scene.grow_reach",) if new["scene"]["grow"] is False else ()  # a box that never grows
        inert += CHANGED_SINCE.get(new["profile"], ())
        differ = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k)
                        and not k.startswith(("name", "profile", "data.options", *inert)))
        assert differ == [], old_name
        assert {k: v for k, v in old["data"]["options"].items() if not k.startswith("crop")} == \
               {k: v for k, v in new["data"]["options"].items() if not k.startswith("crop") and k != "focal_px"}


def test_profiles_choose_the_budget_and_the_device_its_default():
    assert default_profile("cpu") == "realtime" and default_profile("cuda:1") == "paper"
    assert load_config("tum").profile == "realtime"
    assert load_config("tum", ["device=cuda"]).profile == "paper"
    rt, q = load_config("tum", ["profile=realtime"]), load_config("tum", profile="quality")
    assert (rt.tracking.optimizer, q.tracking.optimizer) == ("gauss_newton", "adam")
    assert rt.mapper_process and rt.mapping.schedule == "by_need" and q.mapping.schedule == "every_frame"
    assert load_config("7scenes", profile="quality").data.options["crop_size"] == [240, 320]  # its own
    assert "crop_size" not in load_config("7scenes").data.options  # realtime: by the rule
    for name in PROFILES:
        assert describe(name)
    # ESLAM's sequential order maps inline: the realtime profile's mapping process gives way to parallel=false
    assert not load_config("tum", ["parallel=false"]).mapper_process
    with pytest.raises(SlamInputError, match="'mapper_process' = true needs 'parallel' = true"):
        load_config("tum", ["parallel=false", "mapper_process=true"])


def test_a_profile_file_and_bad_profiles(tmp_path):
    mine = tmp_path / "mine.yaml"
    mine.write_text("tracking: {iters: 3}\nkinds:\n  tum: {tracking: {pixels: 77}}\n")
    cfg = load_config("tum", profile=str(mine))
    assert (cfg.tracking.iters, cfg.tracking.pixels, cfg.profile) == (3, 77, str(mine))
    assert load_config("synthetic", profile=str(mine)).tracking.pixels != 77
    with pytest.raises(SlamInputError, match="unknown profile 'fast'; choose from realtime, quality, paper"):
        load_config("tum", profile="fast")
    with pytest.raises(SlamInputError, match="two profiles"):
        load_config("tum", ["profile=paper"], profile="quality")
    with pytest.raises(SlamInputError, match="old name of --config tum/fr1_rpy --profile quality scene.grow=false"):
        load_config("tum/fr1_rpy-cpu", profile="realtime")
    (tmp_path / "bad.yaml").write_text("kinds: [tum]\n")
    with pytest.raises(SlamInputError, match="'kinds' must map"):
        load_config("tum", profile=str(tmp_path / "bad.yaml"))
    with pytest.raises(SlamInputError, match="profile file not found"):
        load_config("tum", profile=str(tmp_path / "missing.yaml"))


def test_an_old_name_says_what_replaces_it(caplog):
    cfg = load_config("tum/fr1_rpy-cpu-fast")
    assert cfg.name == "tum/fr1_rpy-cpu-fast" and cfg.profile == "realtime" and cfg.scene.grow is False
    assert "is now --config tum/fr1_rpy --profile realtime scene.grow=false" in caplog.text
