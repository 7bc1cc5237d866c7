"""The base the stages build on (docs/architecture.md section 2): the typed configuration
(``core.config``) and its profiles, the engines that run a stage's samples
(``core.engines``), progress reporting (``core.progress``) and the record of what a stage
reads and writes (``core.stage_io``). It imports ``manifests`` and ``speedplus.errors``,
never ``stages`` or ``pipeline``."""
