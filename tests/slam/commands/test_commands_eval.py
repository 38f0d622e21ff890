import json

import numpy as np
import pytest
import trimesh

from slam.cli import main
from slam.data.synthetic import SynthConfig, camera_path
from slam.eval import plot_trajectory, write_tum_trajectory


@pytest.fixture()
def traj_pair(tmp_path):
    gt = camera_path(SynthConfig(frames=60))
    est = gt.copy()
    est[:, :3, 3] += np.array([0.5, -0.2, 0.1])  # removed by alignment
    est[::2, 2, 3] += 0.01  # +-5 mm about the mean after alignment
    est[1::2, 2, 3] -= 0.01
    ts = 1000.0 + np.arange(60) / 30.0
    write_tum_trajectory(tmp_path / "est.txt", ts + 0.001, est)  # slightly different clocks
    write_tum_trajectory(tmp_path / "gt.txt", ts, gt)
    return tmp_path / "est.txt", tmp_path / "gt.txt"


def test_eval_trajectory_json_and_plot(traj_pair, tmp_path, capsys):
    est, gt = traj_pair
    out = tmp_path / "m.json"
    rc = main(["eval", "--trajectory", str(est), "--gt", str(gt), "--json", str(out), "--plot", str(tmp_path / "p.png")])
    assert rc == 0
    table = capsys.readouterr().out
    assert "ATE rmse" in table and "frames paired  60" in table
    data = json.loads(out.read_text())
    for key in ("ate_rmse_m", "ate_mean_m", "ate_median_m", "ate_max_m"):
        assert key in data
    assert data["ate_rmse_m"] == pytest.approx(0.01, abs=2e-4)
    assert (tmp_path / "p.png").stat().st_size > 10_000


def test_eval_mesh_json(tmp_path):
    gt = trimesh.creation.box(extents=[2, 2, 2])
    gt.invert()
    rec = gt.copy()
    rec.apply_translation([0.0, 0.0, 0.01])
    gt.export(tmp_path / "gt.ply")
    rec.export(tmp_path / "rec.ply")
    out = tmp_path / "m.json"
    rc = main(["eval", "--mesh", str(tmp_path / "rec.ply"), "--gt-mesh", str(tmp_path / "gt.ply"),
               "--samples", "20000", "--depth-views", "2", "--depth-box", "-0.1", "-0.1", "-0.1", "0.1", "0.1", "0.1",
               "--json", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    assert set(data) == {"accuracy_m", "completion_m", "completion_ratio", "depth_l1_m"}
    assert data["completion_ratio"] > 0.99 and 0.0 < data["depth_l1_m"] < 0.02
    assert 0.01 <= data["accuracy_m"] < 0.03  # 1 cm shift + sample spacing of 20k points on 24 m^2


def test_eval_bad_inputs_exit_code_2(traj_pair, tmp_path, capsys):
    est, gt = traj_pair
    assert main(["eval", "--trajectory", str(tmp_path / "nope.txt"), "--gt", str(gt)]) == 2
    assert "nope.txt: file not found" in capsys.readouterr().err
    bad = tmp_path / "bad.txt"
    bad.write_text("1000.0 nan 0 0 0 0 0 1\n")
    assert main(["eval", "--trajectory", str(bad), "--gt", str(gt)]) == 2
    err = capsys.readouterr().err
    assert "bad.txt" in err and "NaN" in err and "Traceback" not in err
    assert main(["eval", "--trajectory", str(est)]) == 2
    assert main(["eval", "--mesh", str(tmp_path / "none.ply"), "--gt-mesh", str(tmp_path / "none2.ply")]) == 2
    assert "none.ply" in capsys.readouterr().err


def test_plot_trajectory_writes_png(tmp_path):
    gt = camera_path(SynthConfig(frames=30))
    path = plot_trajectory(gt, gt, tmp_path / "sub" / "t.png")
    assert path.exists() and path.read_bytes()[:4] == b"\x89PNG"
