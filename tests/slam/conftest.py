import pytest

# a few-second SLAM run on the tiny sequence: every stage runs, nothing converges
TINY = ["data.max_frames=6", "tracking.iters=3", "tracking.pixels=100", "mapping.iters=3",
        "mapping.iters_first=5", "mapping.pixels=200", "rendering.n_stratified=8", "rendering.n_importance=4"]
# a box the tiny room's depth fits at first and nears on its x- side (margin 0.15 m) from about frame 5 on: with
# 10 frames the box grows once, in parallel mode while the mapping call of frame 4 is pending
GROWING = ["bound=[[-1.6,2.3],[-0.6,2.3],[-0.3,2.4]]", "scene.grow=true", "scene.grow_margin=0.15"]


@pytest.fixture(scope="session")
def tiny_seq(tmp_path_factory):
    """A 24-frame 60x80 synthetic sequence on disk (Replica layout)."""
    from slam.data.synthetic import SynthConfig, generate

    out = tmp_path_factory.mktemp("tiny_synth")
    generate(out, SynthConfig(frames=24, height=60, width=80, supersample=1))
    return out


class EditedDataset:
    """A dataset wrapper: frames ``no_depth`` have zero depth, frames ``blank`` zero depth and black colour (a
    sensor that saw nothing), frames ``unreadable`` raise as a truncated file does, and the ground truth of frames
    ``bad_gt`` is NaN."""

    def __init__(self, ds, no_depth=(), blank=(), bad_gt=(), unreadable=()):
        import torch

        self.ds, self.no_depth, self.blank, self.unreadable = ds, set(no_depth), set(blank), set(unreadable)
        self.timestamps, self.gt_mesh_path = ds.timestamps, ds.gt_mesh_path
        gt = torch.as_tensor(ds.gt_poses).clone()
        for i in bad_gt:
            gt[i] = float("nan")
        self.gt_poses = gt

    def __len__(self):
        return len(self.ds)

    def __getitem__(self, i):
        import torch

        if i in self.unreadable:
            from slam.errors import SlamInputError

            raise SlamInputError(f"frame {i}: depth PNG truncated (made so by the test)")
        f = self.ds[i]
        if i in self.no_depth or i in self.blank:
            f.depth = torch.zeros_like(torch.as_tensor(f.depth))
        if i in self.blank:
            f.color = torch.zeros_like(torch.as_tensor(f.color))
        return f
