"""The evaluate stage: score ONNX pose models on pairs of synthetic twins and testbed
captures that share their labels (the paper's Table 2 and Figure 12).

The package holds the stage's whole truth (docs/architecture.md section 2): ``stage``, its
``run(config, workspace)`` and ``resolve(config, workspace)`` (what it reads, depends on and
writes); ``config``, its configuration section and its rules; the other modules, its parts.
Kept empty, so that reading the configuration imports none of them.
"""
