"""What a resume checks against its checkpoint before it goes on: the data it reads (every frame's files) and
the kind of device the run computed on."""

import shutil

import pytest
import torch

from tests.slam.conftest import TINY


def _stopped_run(data, out):
    """A run on ``data`` stopped after frame 2 (its checkpoint at frame 3 of 6)."""
    from slam.cli import main

    assert main(["run", "--config", "synthetic", "--profile", "quality", "--data", str(data), "--out", str(out), "--quiet", "--no-mesh", "--stop-after", "3",
                 *TINY]) == 0


@pytest.fixture
def stopped(tiny_seq, tmp_path, capsys):
    """A copy of the tiny sequence and a run on it stopped after three frames."""
    data = tmp_path / "data"
    shutil.copytree(tiny_seq, data)
    _stopped_run(data, tmp_path / "run")
    capsys.readouterr()
    return data, tmp_path / "run"


def _resume(out, capsys, *args):
    from slam.cli import main

    code = main(["run", "--resume", str(out), "--quiet", "--no-mesh", *args])
    return code, capsys.readouterr().err.strip().splitlines()


def test_a_frame_replaced_or_renamed_mid_sequence_is_refused_on_resume(stopped, capsys):
    """20b7b9c compared only the frame counts and the first and last file names: a middle frame replaced by
    another (a re-export, a copy gone wrong) resumed silently on other data."""
    data, out = stopped
    results = data / "results"
    a, b = results / "depth000004.png", results / "depth000002.png"
    assert a.stat().st_size != b.stat().st_size
    keep = a.read_bytes()
    shutil.copyfile(b, a)  # a frame the run has not read yet, replaced
    code, err = _resume(out, capsys)
    assert code == 2 and len(err) == 1 and "the data differ from the checkpointed run's" in err[0]
    a.write_bytes(keep)
    for kind in ("frame", "depth"):  # renamed: the same images and sizes under other names, the same order
        (results / f"{kind}000003.png").rename(results / f"{kind}3.png")
    code, err = _resume(out, capsys)
    assert code == 2 and len(err) == 1 and "the data differ from the checkpointed run's" in err[0]
    for kind in ("frame", "depth"):
        (results / f"{kind}3.png").rename(results / f"{kind}000003.png")
    code, err = _resume(out, capsys)
    assert code == 0, err


def test_a_checkpoint_records_its_device_type_and_a_resume_on_another_is_refused(stopped, capsys):
    """CPU and CUDA compute different numbers: a run resumed on the other kind of device would not end at the
    uninterrupted run's trajectory. A checkpoint written before the record existed resumes as before."""
    _, out = stopped
    ckpt = out / "checkpoint.pt"
    payload = torch.load(ckpt, weights_only=True)
    assert payload["extra"]["run"]["device_type"] == "cpu"
    payload["extra"]["run"]["device_type"] = "cuda"  # as a run on a GPU writes it
    torch.save(payload, ckpt)
    code, err = _resume(out, capsys)
    assert code == 2 and len(err) == 1
    assert "computed on cuda" in err[0] and "on cpu" in err[0] and "uninterrupted" in err[0]
    del payload["extra"]["run"]["device_type"]  # a checkpoint of 20b7b9c
    torch.save(payload, ckpt)
    code, err = _resume(out, capsys)
    assert code == 0, err
