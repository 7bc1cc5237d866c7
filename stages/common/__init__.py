"""The shared domain layer every stage may import, and which imports no stage: frames and
transforms (``geometry``), the camera lens model (``lens``), robot kinematics and the
testbed layout, the target (its folder, looks, the built-in Tango), calibration patterns,
the fusion maths, the RWHE model of the measurement sources, image I/O (OpenImageIO) and
the Mitsuba adapter.

A stage package (``stages/<name>/``) imports this package, ``manifests`` and
``core.config`` (with ``errors``, ``progress``, ``engines``), never another stage;
``tests/test_layers.py`` checks it.
"""
