"""The report stage: a static HTML page, ``W/report/index.html``, with the paper's tables
and figures for this run (no server, no network: open it from the file system).

The package holds the stage's whole truth (docs/architecture.md section 2): ``stage``, its
``run(config, workspace)`` and ``resolve(config, workspace)`` (what it reads, depends on and
writes); it has no configuration keys of its own. The other modules are its parts.
"""
