"""Fault injection for the tests (put on PYTHONPATH by ``tests.conftest.speedplus`` when its
env sets one of these):

- ``SPEEDPLUS_FAULT_KILL_AT_PART=N``: SIGKILL this process while it writes its Nth manifest
  part, after the temporary file is complete and before it is linked into place, to prove
  that interrupted stages resume cleanly;
- ``SPEEDPLUS_FAULT_FAIL_STAGE=NAME``: stage NAME raises once its own ``run`` has written
  all it writes, before the runner completes it, to prove that a chain keeps the stages
  before it and puts back that stage's work (issue 58).

The production paths hold no hook of their own."""

import os
import signal

_AT = os.environ.get("SPEEDPLUS_FAULT_KILL_AT_PART")

if _AT:
    import manifests.io as _io

    _written = 0
    _write = _io.write_table_file

    def _write_then_maybe_die(path, table):  # noqa: ANN001, ANN202 - the wrapped function's own signature
        global _written
        _write(path, table)
        if str(path).endswith(".tmp") and "/staging/" in str(path).replace(os.sep, "/"):
            _written += 1
            if str(_written) == _AT:
                os.kill(os.getpid(), signal.SIGKILL)

    _io.write_table_file = _write_then_maybe_die

_FAIL = os.environ.get("SPEEDPLUS_FAULT_FAIL_STAGE")

if _FAIL:
    import pipeline.registry as _registry

    _load = _registry._load

    def _load_then_fail(entry_point):  # noqa: ANN001, ANN202 - the wrapped function's own signature
        function = _load(entry_point)
        if entry_point != f"stages.{_FAIL.replace('-', '_')}.stage:run":
            return function

        def failing(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            function(*args, **kwargs)
            raise RuntimeError(f"injected fault: stage {_FAIL} failed after its work")

        return failing

    _registry._load = _load_then_fail
