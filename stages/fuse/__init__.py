"""The fuse stage: per dataset capture, the pose from each source through its calibrated
offsets, the motion-capture rejection test, and the Bayesian fusion (docs/architecture.md section 6).

The package holds the stage's whole truth (docs/architecture.md section 2): ``stage``, its
``run(config, workspace)`` and ``resolve(config, workspace)`` (what it reads, depends on and
writes); ``config``, its configuration section and its rules; the other modules, its parts.
Kept empty, so that reading the configuration imports none of them.
"""
