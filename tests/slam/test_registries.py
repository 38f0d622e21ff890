"""One source of truth per registry, walked through: a field kind, a dataset and a loss term are each added here
as one class or function plus one registry line (undone after each test), and the rest of slam takes them up.
The lists that cannot be derived from their registry are pinned to it at the end.

The registries: :data:`tdfields.KINDS` (field kinds), :data:`slam.data.DATASETS` (datasets),
:data:`slam.core.losses.LOSS_TERMS` with :class:`slam.core.losses.LossWeights` (loss terms), and the files under
``slam/configs/representations/`` (:data:`slam.config.REPRESENTATIONS`).
"""

import dataclasses
import json

import numpy as np
import pytest
import torch

import tdfields
from slam.config import FIELD_KINDS, KEYFRAME_STORAGES, REPRESENTATIONS, list_presets, load_config
from slam.core import losses
from slam.core.losses import LOSS_TERMS, LossWeights, total_loss
from slam.data import DATASETS, REFERENCE_OPTIONS, DatasetKind, ReplicaDataset, detect_layout, load_dataset
from slam.errors import SlamInputError


# ------------------------------------------------------------------------------------------- (a) a field kind
class PlaneLine(tdfields.VectorMatrix):
    """A toy kind: one plane times one line, ``f(p) = sum_i M_i(x, y) * v_i(z)``: one of VectorMatrix's three modes
    (its rank, init and complexity come with it)."""

    kind = "toy_plane_line"

    def factor_specs(self):
        return {name: spec for name, spec in super().factor_specs().items() if name.endswith("_xy_z")}

    def terms(self):
        return [("plane_xy_z", "line_xy_z")]


def test_a_field_kind_is_one_class_and_one_registry_line(monkeypatch):
    from slam.model.scene import SceneModel, scene_aabb

    overrides = ["geometry.kind=toy_plane_line", "geometry.rank=3", "bound=[[0,1],[0,1],[0,1]]"]
    with pytest.raises(SlamInputError, match="geometry.kind"):
        load_config("synthetic", overrides, profile="quality")
    monkeypatch.setitem(tdfields.KINDS, PlaneLine.kind, PlaneLine)  # the registry line
    assert "toy_plane_line" in FIELD_KINDS
    cfg = load_config("synthetic", overrides, profile="quality")
    torch.manual_seed(0)
    model = SceneModel(cfg, scene_aabb(cfg.scene.bound, 0.24))
    levels = model.fields["geometry"].levels
    assert all(isinstance(f, PlaneLine) and f.rank == 3 for f in levels)  # the rank reaches a ranked kind
    sdf = model.sdf(torch.rand(50, 3))
    assert sdf.shape == (50,) and torch.isfinite(sdf).all()
    sdf.sum().backward()
    assert all(set(f.factors) == {"plane_xy_z", "line_xy_z"} and f.factors["plane_xy_z"].grad is not None
               for f in levels)


# ---------------------------------------------------------------------------------------------- (b) a dataset
def looks_like_toy(root):
    """The toy layout: a ``toy.json`` marker beside a Replica-layout ``scene/`` folder."""
    return (root / "toy.json").is_file()


class ToyDataset(ReplicaDataset):
    def __init__(self, path, **options):
        super().__init__(path / "scene", **options)


def _write_toy(root, n=3, h=12, w=16):
    import imageio.v3 as iio

    scene = root / "scene"
    (scene / "results").mkdir(parents=True)
    for i in range(n):
        iio.imwrite(scene / "results" / f"frame{i:06d}.png", np.full((h, w, 3), 100 + 10 * i, np.uint8))
        iio.imwrite(scene / "results" / f"depth{i:06d}.png", np.full((h, w), 6553, np.uint16))
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, 1.0]
    np.savetxt(scene / "traj.txt", np.stack([pose.reshape(16)] * n))
    (scene / "cam.json").write_text(json.dumps({"fx": 10.0, "fy": 10.0, "cx": 7.5, "cy": 5.5, "height": h, "width": w}))
    (root / "toy.json").write_text("{}")
    return root


def test_a_dataset_is_one_module_and_one_registry_line(tmp_path, monkeypatch):
    from slam.engine.setup import load_data

    root = _write_toy(tmp_path / "toy_seq")
    with pytest.raises(SlamInputError, match="not a recognised dataset layout"):
        detect_layout(root)
    toy = DatasetKind("toy", ToyDataset, looks_like_toy, "Toy toy.json + scene/")
    monkeypatch.setitem(DATASETS, "toy", toy)  # the registry line
    assert detect_layout(root) == "toy"
    ds = load_dataset(root)
    assert isinstance(ds, ToyDataset) and len(ds) == 3 and ds[1].depth.shape == (12, 16)
    assert isinstance(load_dataset(root, kind="toy", max_frames=2), ToyDataset)
    with pytest.raises(SlamInputError, match=r"or Toy toy.json \+ scene/\)"):  # the layouts it knows, listed
        detect_layout(tmp_path)
    with pytest.raises(SlamInputError, match="unknown dataset kind 'nope'; expected auto, replica, .*, toy"):
        load_dataset(root, kind="nope")
    for kind in ("toy", "auto"):  # a run's config: data.kind names it, or detection finds it
        cfg = load_config("synthetic", [f"data.kind={kind}", f"data.path={root}"], profile="quality")
        assert isinstance(load_data(cfg), ToyDataset)
    cfg = load_config("synthetic", ["data.kind=tum", f"data.path={root}"], profile="quality")
    with pytest.raises(SlamInputError, match="expects tum data but .* looks like toy data"):
        load_data(cfg)


# ------------------------------------------------------------------------------------------- (c) a loss term
def _batch(seed=0, rays=40, samples=16):
    g = torch.Generator().manual_seed(seed)
    depth = torch.rand(rays, generator=g) * 2 + 0.5
    depth[::5] = 0.0  # rays without depth: colour only
    z = depth[:, None] + (torch.rand(rays, samples, generator=g) - 0.7) * 0.6
    sdf = torch.tanh(torch.randn(rays, samples, generator=g)).requires_grad_()
    rendered_depth = (depth + 0.05 * torch.randn(rays, generator=g)).requires_grad_()
    rendered_color = torch.rand(rays, 3, generator=g).requires_grad_()
    return sdf, z, rendered_depth, rendered_color, depth, torch.rand(rays, 3, generator=g), 0.1


def test_a_loss_term_is_one_function_and_one_weight(monkeypatch):
    args = _batch()
    weights = LossWeights(fs=10.0, center=200.0, tail=50.0, depth=1.0, color=5.0)
    five, _ = total_loss(*args, weights)
    monkeypatch.setattr(losses, "LOSS_TERMS", dict(LOSS_TERMS))  # registrations below are undone afterwards

    @losses.loss_term("smooth")  # the registry line
    def smooth(batch):
        return ((batch.sdf[:, 1:] - batch.sdf[:, :-1]) ** 2).mean()

    # its weight: a field of LossWeights (here a subclass; in slam, one more line in LossWeights)
    Weights = dataclasses.make_dataclass("Weights", [("smooth", float, 0.0)], bases=(LossWeights,))
    loss, parts = total_loss(*args, Weights(**dataclasses.asdict(weights), smooth=0.25))
    assert list(parts) == ["fs", "center", "tail", "depth", "color", "smooth"]
    assert torch.equal(loss, five + 0.25 * parts["smooth"]) and parts["smooth"] > 0
    off, _ = total_loss(*args, Weights(**dataclasses.asdict(weights)))
    assert torch.equal(off, five)
    with pytest.raises(ValueError, match="registered twice"):
        losses.loss_term("smooth")(smooth)


# -------------------------------------------------------------------------------- (d) what is pinned, not derived
def test_loss_weights_hold_one_weight_per_term_in_order():
    assert [f.name for f in dataclasses.fields(LossWeights)] == list(LOSS_TERMS)


def test_field_kinds_are_tdfields_kinds_and_ranks_come_from_them():
    assert tuple(FIELD_KINDS) == tuple(sorted(tdfields.KINDS))
    from slam.model.scene import field_spec

    for kind, cls in tdfields.KINDS.items():
        spec = load_config("synthetic", [f"geometry.kind={kind}"], profile="quality").geometry
        assert ("rank" in field_spec(spec, torch.tensor([[0.0, 1.0]] * 3))["levels"][0]) == cls.has_rank


def test_representations_are_the_representation_files():
    from slam.config import CONFIG_DIR

    files = sorted(p.stem for p in (CONFIG_DIR / "representations").glob("*.yaml"))
    assert REPRESENTATIONS[0] == "lrslam" and sorted(REPRESENTATIONS) == files
    for rep in REPRESENTATIONS:
        cfg = load_config("synthetic", [f"representation={rep}"], profile="quality")
        assert cfg.geometry.kind in tdfields.KINDS and cfg.appearance.kind in tdfields.KINDS


def test_presets_name_registered_datasets_with_their_reference_options():
    """``data.kind`` has no schema choices (slam.config sits below slam.data), so every preset is checked here; the
    dataset presets at the paper profile crop and resize as the reference options the registry declares."""
    from slam.data.resize import resize_and_crop
    from slam.data.types import Intrinsics

    for name in list_presets():
        assert load_config(name).data.kind in ("auto", *DATASETS), name
    raw = Intrinsics(517.3, 516.5, 318.6, 255.3, 480, 640)  # the sizes are what matters: every reference is 640x480
    keys = ("crop_size", "crop_edge", "crop_edge_raw", "focal_px")
    for name, ref in REFERENCE_OPTIONS.items():
        options = load_config(name, profile="paper").data.options
        assert resize_and_crop(raw, **{k: options.get(k) for k in keys}) == \
               resize_and_crop(raw, **{k: ref.get(k) for k in keys}), name
    assert set(REFERENCE_OPTIONS) == {n for n, d in DATASETS.items() if d.reference_options is not None}


def test_download_names_come_from_the_registry():
    from slam.data import download

    assert download.DATASETS == ("replica", "tum", "7scenes", "scannet")
    assert set(download.DATASETS) == {n for n, d in DATASETS.items() if d.download}
    assert [n for n in DATASETS if DATASETS[n].download == "request"] == ["scannet"]


def test_every_keyframe_storage_is_one_the_engine_keeps():
    from slam.engine.keyframes import Keyframe, KeyframeStore, bytes_per_keyframe

    assert load_config("synthetic", profile="quality").mapping.keyframe_storage == KEYFRAME_STORAGES[0]
    for storage in KEYFRAME_STORAGES:
        load_config("synthetic", [f"mapping.keyframe_storage={storage}"], profile="quality")
        store = KeyframeStore(storage=storage)
        store.add(Keyframe(0, torch.rand(12, 16, 3), torch.rand(12, 16), torch.tensor([1.0, 0, 0, 0, 0, 0, 0])))
        assert store.nbytes == bytes_per_keyframe(12, 16, storage)
