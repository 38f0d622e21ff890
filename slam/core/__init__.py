"""The functional core of LRSLAM: tensors in, tensors out, no state between calls and no threads.

Poses (:mod:`~slam.core.pose`), camera geometry (:mod:`~slam.core.geometry`), volume rendering of an SDF scene
(:mod:`~slam.core.rendering`), the losses (:mod:`~slam.core.losses`), the optimiser set-up
(:mod:`~slam.core.optim`) and depth ICP (:mod:`~slam.core.odometry`). Nothing here imports the model, the engine or
the run layers (``tests/test_layers.py``).
"""
