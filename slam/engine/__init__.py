"""The SLAM engine: reading frames (:mod:`~slam.engine.frames`), tracking (:mod:`~slam.engine.tracker`, checked by
:mod:`~slam.engine.tracking_guard`, recovered by :mod:`~slam.engine.recovery`), mapping
(:mod:`~slam.engine.mapper`, run inline or beside the tracker by :mod:`~slam.engine.map_worker`), the keyframe
store, and the loop that drives them (:mod:`~slam.engine.system`) with its observers. Writes no files: a run's
outputs and checkpoints are :mod:`slam.run`'s."""
