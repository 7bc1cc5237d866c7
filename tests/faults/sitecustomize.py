"""Fault injection for the tests (put on PYTHONPATH by ``tests.conftest.speedplus`` when its
env sets one of the first three, and by ``tests/core/test_cluster.py`` on its Ray nodes for
the last):

- ``SPEEDPLUS_FAULT_KILL_AT_PART=N``: SIGKILL this process while it writes its Nth manifest
  part, after the temporary file is complete and before it is linked into place, to prove
  that interrupted stages resume cleanly;
- ``SPEEDPLUS_FAULT_FAIL_STAGE=NAME``: stage NAME raises once its own ``run`` has written
  all it writes, before the runner completes it, to prove that a chain keeps the stages
  before it and puts back that stage's work (issue 58);
- ``SPEEDPLUS_FAULT_ENGINE_LOST_AFTER=N``: the engine's map fails (``EngineError``, as when
  a Ray cluster loses its nodes) after yielding N results, to prove that a stage keeps the
  rows it finished when its engine fails (issue 58);
- ``SPEEDPLUS_FAULT_SLOW_RENDER_WHILE=PATH``: while PATH exists, each twin this process
  renders takes a second longer: a node set up with it stays busy long enough to be lost
  mid-stage (``tests/core/test_cluster.py``), however fast the twins are;
- ``SPEEDPLUS_FAULT_SLOW_CAPTURE_WHILE=PATH``: while PATH exists, each virtual capture this
  process makes takes half a second longer: a Ctrl-C falls between the first captures and
  the last (``tests/pipeline/test_workspace_changes.py``), however fast the captures are.

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

    _FAILING = next(f"{entry.package}.stage:run" for entry in _registry.STAGES if entry.name == _FAIL)

    def _load_then_fail(entry_point):  # noqa: ANN001, ANN202 - the wrapped function's own signature
        function = _load(entry_point)
        if entry_point != _FAILING:
            return function

        def failing(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            function(*args, **kwargs)
            raise RuntimeError(f"injected fault: stage {_FAIL} failed after its work")

        return failing

    _registry._load = _load_then_fail

_LOST = os.environ.get("SPEEDPLUS_FAULT_ENGINE_LOST_AFTER")

if _LOST:
    import core.engines as _engines

    _map = _engines.map_engine

    def _map_then_lose(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202 - the wrapped function's own signature
        for count, result in enumerate(_map(*args, **kwargs)):
            if count == int(_LOST):
                raise _engines.EngineError("injected fault: the engine lost its workers")
            yield result

    _engines.map_engine = _map_then_lose


def _slow_while(path: str, owner: type, method: str, seconds: float) -> None:
    """``owner.method`` takes ``seconds`` longer while ``path`` exists."""
    import time

    wrapped = getattr(owner, method)

    def slowly(self, *args):  # noqa: ANN001, ANN002, ANN202 - the wrapped method's own signature
        if os.path.exists(path):
            time.sleep(seconds)
        return wrapped(self, *args)

    setattr(owner, method, slowly)


if os.environ.get("SPEEDPLUS_FAULT_SLOW_RENDER_WHILE"):
    import stages.render.worker as _worker

    _slow_while(os.environ["SPEEDPLUS_FAULT_SLOW_RENDER_WHILE"], _worker.RenderWorker, "render", 1.0)

if os.environ.get("SPEEDPLUS_FAULT_SLOW_CAPTURE_WHILE"):
    import stages.acquire.virtual as _virtual

    _slow_while(os.environ["SPEEDPLUS_FAULT_SLOW_CAPTURE_WHILE"], _virtual.VirtualTestbed, "capture", 0.5)
