"""SPEED+ builder's public names for code that uses it: ``speedplus.data`` (the ML loaders,
docs/loaders.md) and ``speedplus.errors`` (the errors every layer raises for bad input).
Importing this package imports neither; the pipeline itself is ``pipeline``, ``stages`` and
``manifests`` (docs/architecture.md section 2)."""
