"""The acquire stage: drive a testbed backend through its samples and record what it
measures (``captures``), the images, and, for the virtual testbed, the hidden ``truth``.

The package holds the stage's whole truth (docs/architecture.md section 2): ``stage``, its
``run(config, workspace)`` and ``resolve(config, workspace)`` (what it reads, depends on and
writes); ``config``, its configuration section and its rules; the other modules, its parts.
Kept empty, so that reading the configuration imports none of them.
"""
