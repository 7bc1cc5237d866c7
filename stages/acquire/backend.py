"""The testbed interface every acquisition backend implements.

``samples()`` lists what to capture (the plan's rows for the virtual testbed, the
recorded samples for a replay); ``capture(sample)`` moves the testbed there and returns
one ``captures`` row (and a ``truth`` row when the backend knows the truth) with its
image: a replay writes it into the workspace itself, the virtual testbed (whose workers
may run on other machines) returns its bytes in ``files`` for the driver to write.
``session()`` describes the capture session for the stages after it: the calibration
pattern, the camera and the measurement sources.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

from manifests.sidecars import Session


@dataclass(frozen=True)
class CaptureRecord:
    captures: dict[str, Any]
    truth: dict[str, Any] | None
    #: files still to be written, by workspace path (``core.engines.store``)
    files: dict[str, bytes] = field(default_factory=dict)


class Testbed(Protocol):
    def samples(self) -> list[dict[str, Any]]: ...

    def capture(self, sample: dict[str, Any]) -> CaptureRecord: ...

    def session(self) -> Session: ...


