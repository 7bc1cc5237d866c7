"""What a stage reads, writes and depends on under a configuration: the record each stage's
own ``resolve(config, workspace)`` returns (docs/architecture.md section 1), the one truth
the runner fingerprints and the CLI and ``status`` read. It imports nothing of the project,
so every stage can build one."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Resolved:
    """A stage's input manifests (their completion markers), configuration sections, extra
    fingerprint content and output manifests for one configuration."""

    inputs: tuple[str, ...]
    sections: tuple[str, ...]
    extra: dict[str, Any]
    outputs: tuple[str, ...]
    #: results kept per member (evaluate: per model): name -> digest. Members are added
    #: without redoing the others; their digests are not in the fingerprint but in the markers
    members: dict[str, str] = field(default_factory=dict)
    #: the configuration key that lists the members (left out of the fingerprint) and the
    #: output column that names a row's member
    member_key: str | None = None
    member_column: str | None = None
    #: members and ``extra`` keys whose files a stage of this workspace makes (evaluate: the
    #: models train-reference writes in W/models/): a chain redoes the stage when only they
    #: changed, as when an input manifest was redone
    retrained: frozenset[str] = frozenset()
