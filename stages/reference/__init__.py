"""The train-reference stage: the reference keypoint CNNs (torch) trained on the synthetic
training set (the ``train`` manifest), the plain one and the augmented one, and the
detector that gives their own crop (``reference.variants``), each exported to ONNX with its
contract as ``W/models/<name>.onnx`` with its model card ``W/models/<name>.json``, and
recorded as a row of the ``models`` manifest. A keypoint model's training checkpoints after
every epoch (``W/models/<name>.checkpoint.pt``), so an interrupted run resumes where it
stopped; the detector (minutes) starts again.

The package holds the stage's whole truth (docs/architecture.md section 2): ``stage``, its
``run(config, workspace)`` and ``resolve(config, workspace)`` (what it reads, depends on and
writes); ``config``, its configuration section and its rules; the other modules, its parts.
Kept empty, so that reading the configuration imports none of them.
"""
