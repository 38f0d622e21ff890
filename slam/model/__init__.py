"""The scene model: the geometry and appearance fields with their decoders (:mod:`~slam.model.scene`), and meshing
it (:mod:`~slam.model.mesher`). Built on :mod:`slam.core`; knows nothing of the loop that fits it."""
