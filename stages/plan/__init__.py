"""The plan stage: relative poses to capture and the testbed commands that realise them.

The package holds the stage's whole truth (docs/architecture.md section 2): ``stage``, its
``run(config, workspace)`` and ``resolve(config, workspace)`` (what it reads, depends on and
writes); ``config``, its configuration sections and their rules; the other modules, its parts.
Kept empty, so that reading the configuration imports none of them.
"""
