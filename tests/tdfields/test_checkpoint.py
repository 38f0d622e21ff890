import json

import pytest
import torch

import tdfields
from tdfields.__main__ import main as tdfields_main

BOX = [[0, 1], [0, 1], [0, 1]]


def test_save_load_roundtrip(tmp_path):
    torch.manual_seed(0)
    h = tdfields.build({"kind": "hybrid", "fields": {
        "geometry": {"kind": "cp", "aabb": BOX, "cell_size": [0.5, 0.1], "channels": 4, "rank": 2},
        "appearance": {"kind": "six_axis", "aabb": BOX, "cell_size": 0.2, "channels": 3, "rank": 2}}})
    tdfields.resize(h["appearance"], grid_shape=(7, 6, 5))  # the saved spec must carry the current grid
    path = tdfields.save(tmp_path / "scene.pt", h, config={"note": "test"}, extra={"step": 7})
    payload = tdfields.load(path)
    assert payload["version"] == tdfields.__version__
    assert payload["config"] == {"note": "test"} and payload["extra"] == {"step": 7}
    h2 = tdfields.load_field(path)
    x = torch.rand(9, 3)
    for name in ("geometry", "appearance"):
        torch.testing.assert_close(h2(x)[name], h(x)[name])
    assert h2["appearance"].grid_shape == (7, 6, 5)


def test_load_field_reads_a_checkpoint_with_the_old_hybrid_names(tmp_path):
    """Hybrids were saved as ``fields.<name>.*`` before they became a ModuleDict (checkpoints up to this change)."""
    torch.manual_seed(0)
    h = tdfields.build({"kind": "hybrid", "fields": {
        "geometry": {"kind": "cp", "aabb": BOX, "cell_size": [0.5, 0.1], "channels": 4, "rank": 2},
        "appearance": {"kind": "six_axis", "aabb": BOX, "cell_size": 0.2, "channels": 3, "rank": 2}}})
    path = tdfields.save(tmp_path / "new.pt", h)
    payload = torch.load(path, weights_only=True)
    assert "geometry.levels.0.factors.x" in payload["state_dict"]
    payload["state_dict"] = {f"fields.{k}": v for k, v in payload["state_dict"].items()}
    torch.save(payload, tmp_path / "old.pt")
    h2 = tdfields.load_field(tmp_path / "old.pt")
    for (name, a), b in zip(h.state_dict().items(), h2.state_dict().values()):
        assert torch.equal(a, b), name


def test_load_errors_name_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.pt"):
        tdfields.load(tmp_path / "nope.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="bad.pt"):
        tdfields.load(bad)
    other = tmp_path / "other.pt"
    torch.save({"a": 1}, other)
    with pytest.raises(ValueError, match="not a tdfields checkpoint"):
        tdfields.load(other)


def test_cli_report_yaml_and_checkpoint(tmp_path, capsys):
    spec = tmp_path / "f.yaml"
    spec.write_text("kind: cp\naabb: [[0, 1], [0, 1], [0, 1]]\ncell_size: [0.5, 0.1]\nchannels: 4\nrank: 2\n")
    out = tmp_path / "r.json"
    assert tdfields_main(["report", str(spec), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "cp" in text and "O(n)" in text
    data = json.loads(out.read_text())
    assert data["total_parameters"] == 2 * 4 * (2 * 3 + 10 * 3)
    ck = tdfields.save(tmp_path / "c.pt", tdfields.build(spec))
    assert tdfields_main(["report", str(ck)]) == 0
    assert tdfields_main(["report", str(tmp_path / "missing.yaml")]) == 2
    assert "missing.yaml" in capsys.readouterr().err
