"""The top (docs/architecture.md section 2): the CLI (``pipeline.cli``), the registry of
stages (``pipeline.registry``, the one place that names them) and the runner
(``pipeline.runner``). Nothing imports it."""
