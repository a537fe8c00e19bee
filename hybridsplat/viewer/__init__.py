"""``hybridsplat view``: a local browser viewer of a project's merged result (viser), with measurement.

- :mod:`hybridsplat.viewer.project` — the project's files the viewer reads and writes.
- :mod:`hybridsplat.viewer.scene` — loading splats, clouds, meshes and cameras into viewer-ready arrays.
- :mod:`hybridsplat.viewer.app` — the viser application (scene, GUI, picking, ellipsoids).

The geometry of measurement lives in :mod:`eval.measure`; this package only wires it to clicks.
"""
