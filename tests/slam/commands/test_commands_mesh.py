"""``lrslam mesh``: a run checkpoint, also one written with the scene's earlier parameter names, rebuilds the run."""

import pytest
import torch

import tdfields
from slam.commands.mesh import load_run_checkpoint
from slam.config import load_config
from slam.errors import SlamInputError
from slam.model.scene import SceneModel, scene_aabb


def _save_run(data, path, keyframes=(0,), overrides=()):
    """What ``lrslam run`` saves for a 4-frame run on ``data`` (weights untrained, poses exact)."""
    from slam.data import load_dataset

    cfg = load_config("synthetic", [f"data.path={data}", "representation=sa_cp", "meshing.resolution=0.1",
                                    *overrides], profile="quality")
    ds = load_dataset(data)
    aabb = scene_aabb(cfg.scene.bound, cfg.scene.bound_dividable)
    torch.manual_seed(0)
    scene = SceneModel(cfg, aabb)
    k = ds.intrinsics
    extra = {"poses": ds.gt_poses[:4], "frame_indices": [0, 1, 2, 3], "timestamps": ds.timestamps[:4],
             "bound": cfg.scene.bound, "marching_cubes_bound": cfg.scene.bound, "aabb": aabb.tolist(),
             "intrinsics": k.as_dict(), "keyframe_indices": list(keyframes),
             "keyframe_poses": ds.gt_poses[list(keyframes)]}
    path = tdfields.save(path, scene, config=cfg.to_dict(), extra=extra)
    return path, cfg, scene


@pytest.fixture()
def checkpoint(tiny_seq, tmp_path):
    return _save_run(tiny_seq, tmp_path / "checkpoint.pt")


def test_mesh_takes_the_run_folder_and_survives_frames_it_cannot_read(tiny_seq, tmp_path, capsys):
    """A depth PNG the run skipped as unreadable must not stop ``lrslam mesh``: that frame is culled by its view
    frustum only, and a keyframe among them gives no hull points."""
    import shutil

    from slam.cli import main

    data = tmp_path / "data"
    shutil.copytree(tiny_seq, data)
    png = data / "results" / "depth000002.png"
    png.write_bytes(png.read_bytes()[:100])
    (tmp_path / "run").mkdir()
    _save_run(data, tmp_path / "run" / "checkpoint.pt", keyframes=(0, 2))
    assert main(["mesh", str(tmp_path / "run")]) == 0
    err = capsys.readouterr().err
    assert "1 frame(s) of the run cannot be read" in err and "Traceback" not in err
    assert (tmp_path / "run" / "mesh_0.1.ply").is_file()


def test_mesh_of_a_run_whose_scratch_folder_is_gone(tiny_seq, tmp_path):
    """The run's keyframe spill folder (scratch, removed after the run or absent on the machine the run folder
    was moved to) is never used by meshing: it must not stop ``lrslam mesh``."""
    from slam.cli import main

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    (tmp_path / "run").mkdir()
    _save_run(tiny_seq, tmp_path / "run" / "checkpoint.pt",
              overrides=[f"mapping.keyframe_spill_dir={scratch}", "mapping.keyframes_in_memory=1"])
    scratch.rmdir()
    assert main(["mesh", str(tmp_path / "run"), "--no-cull", "--resolution", "0.2"]) == 0
    assert (tmp_path / "run" / "mesh_0.2.ply").is_file()


@pytest.mark.parametrize("res", ["0", "-0.1", "nan", "inf", "2000"])
def test_a_resolution_out_of_range_is_refused_in_one_line(checkpoint, tmp_path, capsys, res):
    """0 used to mean "the run's" (falsy), infinity reached marching cubes; the run's own meshing.resolution range
    applies (> 0 and <= 1000 metres). Nothing is written."""
    from slam.cli import main

    path, _, _ = checkpoint
    assert main(["mesh", str(path), f"--resolution={res}", "--no-cull", "--out", str(tmp_path / "m.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--resolution = {res}" in err[0] and "must be > 0 and <= 1000 (metres)" in err[0]
    assert not (tmp_path / "m.ply").exists()


def test_checkpoint_rebuilds_the_config_and_the_weights(checkpoint):
    path, cfg, scene = checkpoint
    cfg2, scene2, extra = load_run_checkpoint(path)
    assert cfg2 == cfg
    assert list(scene2.state_dict()) == list(scene.state_dict())
    assert all(torch.equal(a, b) for a, b in zip(scene.state_dict().values(), scene2.state_dict().values()))
    assert extra["frame_indices"] == [0, 1, 2, 3] and not scene2.training


def test_checkpoint_with_the_old_parameter_names_still_loads(checkpoint, tmp_path):
    """Runs saved the scene as fields.fields.geometry.* before tdfields.Hybrid became a ModuleDict."""
    path, _, scene = checkpoint
    payload = torch.load(path, weights_only=True)
    payload["state_dict"] = {k.replace("fields.", "fields.fields.", 1) if k.startswith("fields.") else k: v
                             for k, v in payload["state_dict"].items()}
    assert any(k.startswith("fields.fields.geometry.levels.1.factors.") for k in payload["state_dict"])
    old = tmp_path / "old.pt"
    torch.save(payload, old)
    _, scene2, _ = load_run_checkpoint(old)
    assert all(torch.equal(a, b) for a, b in zip(scene.state_dict().values(), scene2.state_dict().values()))
    from slam.cli import main

    assert main(["mesh", str(old), "--no-cull", "--out", str(tmp_path / "m.ply")]) == 0
    assert (tmp_path / "m.ply").is_file()


def test_not_a_run_checkpoint_is_an_input_error(tmp_path):
    path = tdfields.save(tmp_path / "field.pt", tdfields.build(
        {"kind": "cp", "aabb": [[0, 1], [0, 1], [0, 1]], "cell_size": 0.5, "channels": 2, "rank": 1}))
    with pytest.raises(SlamInputError, match="not an lrslam run checkpoint"):
        load_run_checkpoint(path)
    with pytest.raises(SlamInputError, match="checkpoint not found"):
        load_run_checkpoint(tmp_path / "missing.pt")


@pytest.mark.slow
def test_mesh_without_the_data_uses_the_hull_stored_in_the_checkpoint(tiny_seq, tmp_path):
    """The run's own mesh, rebuilt by ``lrslam mesh`` after its data folder is gone, has the same geometry (the
    checkpoint holds the hull's points and the observed voxels). It is a part of the dense extraction's mesh
    (``meshing.block_cells=0``): the same surface near the keyframes' depth, none of what this barely trained map
    has away from it."""
    import shutil

    import trimesh
    from scipy.spatial import cKDTree

    from slam.cli import main
    from slam.run.runner import run_to_folder
    from tests.slam.conftest import TINY

    data = tmp_path / "data"
    shutil.copytree(tiny_seq, data)
    cfg = load_config("synthetic", [f"data.path={data}", *TINY, "meshing.cull=false", "meshing.resolution=0.05"], profile="quality")
    run_to_folder(cfg, tmp_path / "run", progress=False, mesh=True)
    shutil.rmtree(data)
    assert main(["mesh", str(tmp_path / "run" / "checkpoint.pt"), "--no-cull", "--out", str(tmp_path / "m.ply")]) == 0
    a = trimesh.load(tmp_path / "run" / "mesh.ply", process=False)
    b = trimesh.load(tmp_path / "m.ply", process=False)
    assert len(a.faces) > 0 and a.vertices.shape == b.vertices.shape
    assert abs(a.vertices - b.vertices).max() < 1e-6
    assert main(["mesh", str(tmp_path / "run"), "--no-cull", "--out", str(tmp_path / "d.ply"),
                 "--set", "meshing.block_cells=0"]) == 0
    d = trimesh.load(tmp_path / "d.ply", process=False)
    assert len(a.faces) < len(d.faces) and cKDTree(d.vertices).query(a.vertices)[0].max() < 1e-5


def test_mesh_takes_meshing_overrides_only(checkpoint, tmp_path, capsys):
    """``--set meshing.KEY=VALUE`` changes how this mesh is made (checked like a run's); the other sections made the map:
    refused in one line, nothing written."""
    from slam.cli import main

    path, _, _ = checkpoint
    assert main(["mesh", str(path), "--no-cull", "--out", str(tmp_path / "m.ply"), "--set", "meshing.block_cells=0",
                 "--set=meshing.batch=1000"]) == 0
    for bad in ("scene.truncation=0.1", "meshing.block_cells=-1"):
        capsys.readouterr()
        assert main(["mesh", str(path), "--no-cull", "--out", str(tmp_path / "n.ply"), "--set", bad]) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not (tmp_path / "n.ply").exists()
