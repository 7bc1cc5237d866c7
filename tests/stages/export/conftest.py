"""The export tests use tests/conftest.py's ``rendered`` and ``exported`` workspaces."""
