"""Loop closure (docs/loops.md): place recognition over keyframes, geometric verification, a pose graph, and the
correction it makes to every frame's pose.

Layers, each importing only those before it: :mod:`~slam.loop.features` (ORB keypoints and depth points of a
keyframe), :mod:`~slam.loop.vocabulary` (a bag of words learned from the sequence), :mod:`~slam.loop.icp` and
:mod:`~slam.loop.verify` (is a candidate the same place, and where), :mod:`~slam.loop.graph` (the pose graph),
:mod:`~slam.loop.correct` (its correction carried to every frame), :mod:`~slam.loop.closer` (all of it beside the
tracker).
"""
