"""Adapters from tdfields to other libraries, one module each, each importing its library itself.

Nothing here is imported by ``import tdfields``: a missing third-party library only matters to the code that asks
for its adapter.

* :mod:`tdfields.integrations.nerfstudio`: any field spec as a nerfstudio ``Encoding`` (``pip install
  "tdfields[nerfstudio]"``, see docs/nerf.md, "nerfstudio plugin").
* :mod:`tdfields.integrations.nerfstudio_model` and :mod:`tdfields.integrations.nerfstudio_methods`: TensoRF-style
  models on tdfields encodings and the ``ns-train`` methods ``tdfields-cp``, ``tdfields-six-axis`` and
  ``tdfields-hybrid`` (registered through the ``nerfstudio.method_configs`` entry points).
"""
