"""Fault injection for the tests that kill a command mid-write (put on PYTHONPATH by
``tests.conftest.speedplus`` when its env sets ``SPEEDPLUS_FAULT_KILL_AT_PART``): SIGKILL
this process while it writes its Nth manifest part, after the temporary file is complete and
before it is linked into place, to prove that interrupted stages resume cleanly. The
production write path holds no hook of its own."""

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
