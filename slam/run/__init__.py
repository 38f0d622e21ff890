"""A run to a folder: its outputs (:mod:`~slam.run.outputs`), checkpoints and resuming
(:mod:`~slam.run.checkpoint`), the run itself with interrupts and periodic checkpoints
(:mod:`~slam.run.runner`), and the live viewer (:mod:`~slam.run.viewer`)."""
