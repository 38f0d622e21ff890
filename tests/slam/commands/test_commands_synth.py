from slam.cli import main
from slam.data import load_dataset


def test_synth_command(tmp_path, capsys):
    out = tmp_path / "seq"
    rc = main(["synth", "--out", str(out), "--frames", "3", "--height", "24", "--width", "32", "--depth-noise", "0.005"])
    assert rc == 0
    assert "wrote 3 frames 24x32" in capsys.readouterr().out
    ds = load_dataset(out)
    assert len(ds) == 3 and ds.intrinsics.width == 32


def test_synth_refuses_foreign_folder(tmp_path, capsys):
    (tmp_path / "keep.txt").write_text("mine")
    assert main(["synth", "--out", str(tmp_path), "--frames", "2"]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert (tmp_path / "keep.txt").exists()
