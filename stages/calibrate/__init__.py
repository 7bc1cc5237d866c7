"""The calibrate stage: offsets of every measurement source, their uncertainty, the
rejection thresholds of motion capture, and the paper's Table 1 (in-sample, k-fold
cross-validated, and against the hidden truth when there is one).

The package holds the stage's whole truth (docs/architecture.md section 2): ``stage``, its
``run(config, workspace)`` and ``resolve(config, workspace)`` (what it reads, depends on and
writes); ``config``, its configuration section and its rules; the other modules, its parts.
Kept empty, so that reading the configuration imports none of them.
"""
