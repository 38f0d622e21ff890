"""LRSLAM Table 1 (and ESLAM's counts), reproduced from the modules themselves."""

import pytest

import tdfields

SCENES = {
    "replica/room0": [[-1.9, 7.9], [-2.2, 4.5], [-2.5, 2.3]],
    "scannet/scene0000": [[-2.0, 11.0], [-2.0, 11.5], [-2.0, 5.5]],
    "tum/fr1_desk": [[-4.6, 2.6], [-3.3, 3.2], [-2.0, 4.9]],
}
DECODERS = 2693  # 1,329 (SDF) + 1,363 (RGB) + 1 (beta)

# (geometry, appearance, total) in millions, as printed in the paper (2 decimals)
PAPER = {
    ("replica/room0", "eslam"): (1.40, 5.38, 6.79),
    ("replica/room0", "lrslam"): (0.03, 0.83, 0.86),
    ("scannet/scene0000", "eslam"): (3.66, 13.98, 17.63),
    ("scannet/scene0000", "lrslam"): (0.05, 1.33, 1.38),
    ("tum/fr1_desk", "eslam"): (1.40, 5.36, 6.77),
    ("tum/fr1_desk", "lrslam"): (0.03, 0.81, 0.84),
}


def scene_fields(bound, representation):
    box = tdfields.enlarge_bounds(bound, 0.24)
    if representation == "eslam":
        geo = {"kind": "triplane", "aabb": box.tolist(), "cell_size": [0.24, 0.06], "channels": 32}
        app = {"kind": "triplane", "aabb": box.tolist(), "cell_size": [0.24, 0.03], "channels": 32}
    else:
        geo = {"kind": "cp", "aabb": box.tolist(), "cell_size": [0.24, 0.06], "channels": 32, "rank": 2}
        app = {"kind": "six_axis", "aabb": box.tolist(), "cell_size": [0.24, 0.03], "channels": 32, "rank": 16}
    return tdfields.build({"kind": "hybrid", "fields": {"geometry": geo, "appearance": app}})


@pytest.mark.parametrize("scene, representation", sorted(PAPER))
def test_table1(scene, representation):
    hybrid = scene_fields(SCENES[scene], representation)
    rep = tdfields.report(hybrid)
    geo = rep.parameters_under("geometry")
    app = rep.parameters_under("appearance")
    total = geo + app + DECODERS
    paper = PAPER[scene, representation]
    assert (round(geo / 1e6, 2), round(app / 1e6, 2), round(total / 1e6, 2)) == paper


def test_exact_counts_room0():
    eslam = tdfields.report(scene_fields(SCENES["replica/room0"], "eslam"))
    assert eslam.parameters_under("geometry") == 1_402_848
    assert eslam.parameters_under("appearance") == 5_383_904
    lr = tdfields.report(scene_fields(SCENES["replica/room0"], "lrslam"))
    assert lr.parameters_under("geometry") == 28_672
    assert lr.parameters_under("appearance") == 827_392


def test_scannet_eslam_total_matches_paper_table4():
    rep = tdfields.report(scene_fields(SCENES["scannet/scene0000"], "eslam"))
    assert rep.total_parameters + DECODERS == 17_633_349


def test_decoder_counts():
    sdf = tdfields.MLPDecoder(64, 1, hidden=16, output_activation="tanh")
    rgb = tdfields.MLPDecoder(64, 3, hidden=16, output_activation="sigmoid")
    assert sum(p.numel() for p in sdf.parameters()) == 1329
    assert sum(p.numel() for p in rgb.parameters()) == 1363
