"""A bounded cache of a pure computation's answers, shared by the modules that keep them
(a camera's pixel rays, an EXR's uniform tiles, a pattern's detections): by key, the
least recently used dropped first, safe to share between threads. Two threads that miss
the same key both compute it, and either answer is the answer: the computations kept
here are deterministic."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

Value = TypeVar("Value")


class Kept(Generic[Value]):
    """At most ``size`` answers, by key."""

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f"a cache of at least one answer, got {size}")
        self.size = size
        self._answers: OrderedDict[Hashable, Value] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: Hashable, compute: Callable[[], Value]) -> Value:
        """The answer kept for ``key``, else ``compute()``'s, kept (computed outside the lock)."""
        with self._lock:
            if key in self._answers:
                self._answers.move_to_end(key)
                return self._answers[key]
        answer = compute()
        with self._lock:
            self._answers[key] = answer
            self._answers.move_to_end(key)
            while len(self._answers) > self.size:
                self._answers.popitem(last=False)
        return answer

    def __len__(self) -> int:
        return len(self._answers)
