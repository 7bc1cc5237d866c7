"""The export stage: the labelled testbed images, their synthetic twins and the training set
as a SPEED+ dataset (the Stanford devkits; ``stages.export.speedplus``), a BOP dataset
(bop_toolkit; ``stages.export.bop``) or, for a trajectory plan, SHIRT's sequences
(``stages.export.shirt``); the plan as the robots' programs (``stages.export.robot``); the
captures as a lab logger's session (``stages.export.session``); in ``export.out`` (default
``W/export/<format>``: each format its own folder, never another's).

The package holds the stage's whole truth (docs/architecture.md section 2): ``stage``, its
``run(config, workspace)`` and ``resolve(config, workspace)`` (what it reads, depends on and
writes); ``config``, its configuration section and its rules; the other modules, its parts.
Kept empty, so that reading the configuration imports none of them.
"""
