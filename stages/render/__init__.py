"""The render stage: Mitsuba 3 synthetic twins of the labelled testbed captures (same pose,
same camera and lens, light aligned with the testbed light), or the synthetic training set.

The package holds the stage's whole truth (docs/architecture.md section 2): ``stage``, its
``run(config, workspace)`` and ``resolve(config, workspace)`` (what it reads, depends on and
writes); ``config``, its configuration section and its rules; the other modules, its parts.
Kept empty, so that reading the configuration imports none of them.
"""
