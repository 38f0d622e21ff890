"""The options of a synthetic sequence: image size, camera, noise, path speed, anti-aliasing."""

from __future__ import annotations

from dataclasses import dataclass

from slam.data.types import Intrinsics
from slam.errors import SlamInputError


@dataclass
class SynthConfig:
    """Synthetic sequence options.

    Attributes:
        scene: ``room`` (the 4 m room, a loop around its centre) or ``walk`` (three connected rooms, 20 m, walked
            through and back: :mod:`slam.data.synthetic.walk`; use :func:`walk_config` for its defaults).
        seed: texture, colour and noise seed (geometry is fixed; the path wobble phases depend on it).
        frames: number of frames (30 Hz timestamps ``i / 30``).
        height, width: image size in pixels.
        focal_scale: ``fx = fy = focal_scale * width`` (0.6 gives a ~80 deg horizontal field of view).
        depth_noise_sigma: std (metres) of i.i.d. Gaussian noise added to valid depth.
        sensor_holes: Kinect-like depth: depth-dependent noise ``0.0012 + 0.0019 (z - 0.4)^2`` m, no depth
            closer than 0.4 m or past 4.5 m, holes at depth edges, at grazing angles and in random blobs.
        color_noise_sigma: std of i.i.d. Gaussian colour noise (colour in [0, 1]).
        loop_frames: frames per full loop around the room (sets the speed: ~1.4 cm, ~0.9 deg per frame) or
            along the walk (2100: ~0.57 m/s).
        path_radius: radius (m) of the camera loop around the room centre.
        supersample: colour anti-aliasing: pixels at occluding edges, creases and curved surfaces average
            ``supersample^2`` rays (flat interiors take one, the texture being smooth at pixel scale); depth
            always uses the centre ray.
    """

    seed: int = 0
    frames: int = 120
    scene: str = "room"
    height: int = 120
    width: int = 160
    focal_scale: float = 0.6
    depth_noise_sigma: float = 0.0
    sensor_holes: bool = False
    color_noise_sigma: float = 0.0
    loop_frames: int = 400
    path_radius: float = 0.9
    supersample: int = 2

    def intrinsics(self) -> Intrinsics:
        f = self.focal_scale * self.width
        return Intrinsics(f, f, (self.width - 1) / 2.0, (self.height - 1) / 2.0, self.height, self.width)

    def validate(self) -> None:
        if self.frames < 1 or self.height < 8 or self.width < 8 or self.supersample < 1 or self.loop_frames < 8:
            raise SlamInputError(f"synthetic config out of range: {self}")
        if self.depth_noise_sigma < 0 or self.color_noise_sigma < 0:
            raise SlamInputError("synthetic config: noise sigmas must be >= 0")
        if self.scene not in SCENES:
            raise SlamInputError(f"synthetic scene must be one of {', '.join(SCENES)}, got '{self.scene}'")


#: the synthetic scenes
SCENES = ("room", "walk")
#: frames of one whole walk (there and back) at 30 Hz
WALK_FRAMES = 2100


def walk_config(frames: int = WALK_FRAMES, **kw) -> SynthConfig:
    """The walk's defaults: ``frames`` of the 2100-frame walk (an excerpt is the walk's first frames, byte for
    byte), 120x160, Kinect-like depth (``sensor_holes``), colour anti-aliasing off (2x faster)."""
    opts = {"scene": "walk", "frames": frames, "loop_frames": WALK_FRAMES, "sensor_holes": True, "supersample": 1}
    return SynthConfig(**{**opts, **kw})
