"""Which topics of a ROS bag hold the colour and depth images and the colour camera's CameraInfo: found by type and
name, or named by the loader's options (the rules: :mod:`slam.data.bag`)."""

from __future__ import annotations

from slam.data.bag_messages import CAMERA_INFO, COMPRESSED, IMAGE, Bag
from slam.errors import SlamInputError

__all__ = ["find_topics"]


def _given(bag: Bag, option: str, given: str, types: tuple[str, ...]) -> str:
    """The topic an option names, checked to exist with one of ``types``."""
    if given not in bag.topics:
        raise SlamInputError(f"{bag.path}: data.options.{option} = {given!r} is not a topic of the bag; its "
                             f"{' / '.join(types)} topics: {bag.describe(types)}")
    if bag.topics[given][0] not in types:
        raise SlamInputError(f"{bag.path}: data.options.{option} = {given!r} is a {bag.topics[given][0]} topic, "
                             f"expected {' or '.join(types)}")
    return given


def _pick(bag: Bag, option: str, given: str | None, types: tuple[str, ...], what: str, candidates, rank) -> str:
    """The topic ``given`` (checked), else the best-ranked of ``candidates`` (lowest ``rank``); SlamInputError
    naming the topics when there is none or several tie."""
    if given is not None:
        return _given(bag, option, given, types)
    found = sorted(candidates, key=rank)
    if not found:
        raise SlamInputError(f"{bag.path}: no {what} topic; the bag has: {bag.describe()} "
                             f"(name one with data.options.{option})")
    tied = [t for t in found if rank(t) == rank(found[0])]
    if len(tied) > 1:
        raise SlamInputError(f"{bag.path}: several {what} topics ({', '.join(tied)}); name one with "
                             f"data.options.{option}")
    return found[0]


def find_topics(bag: Bag, color_topic, depth_topic, info_topic) -> tuple[str, str, str | None]:
    """The colour, depth and camera-info topics (:mod:`slam.data.bag` says how they are found); the last None when
    the bag has none."""
    if not any(c for _, c in bag.topics.values()):
        raise SlamInputError(f"{bag.path}: the {bag.what} holds no messages (topics: {bag.describe()})")
    live = {n: t for n, (t, c) in bag.topics.items() if c > 0}
    low = {n: n.lower() for n in live}
    color = _pick(
        bag, "color_topic", color_topic, (IMAGE, COMPRESSED), "colour",
        [n for n, t in live.items() if t in (IMAGE, COMPRESSED) and "depth" not in low[n]
         and any(w in low[n] for w in ("rgb", "color", "colour"))],
        lambda n: (live[n] == COMPRESSED, "mono" in low[n]))
    depth = _pick(
        bag, "depth_topic", depth_topic, (IMAGE,), "depth (sensor_msgs/Image with 'depth' in its name)",
        [n for n, t in live.items() if t == IMAGE and "depth" in low[n]],
        lambda n: not any(w in low[n] for w in ("aligned", "registered")))
    if info_topic is not None:
        return color, depth, _given(bag, "camera_info_topic", info_topic, (CAMERA_INFO,))
    infos = [n for n, t in live.items() if t == CAMERA_INFO]
    parts = color.split("/")
    for k in range(len(parts) - 1, 0, -1):  # the colour topic's own namespace first, then its parents'
        name = "/".join(parts[:k]) + "/camera_info"
        if name in infos:
            return color, depth, name
    colour_infos = [n for n in infos if "depth" not in low[n] and any(w in low[n] for w in ("rgb", "color", "colour"))]
    return color, depth, colour_infos[0] if len(colour_infos) == 1 else None
