"""The plan command's own options (``core.command``: the CLI puts the common ones beside
them)."""

from __future__ import annotations

from core.command import FacilityOption, Request, TargetOption, folders


def options(target: TargetOption = None, facility: FacilityOption = None) -> Request:
    """Run the plan stage: relative poses, view, light and robot/rail commands, for the target
    (--target DIR, a target folder; default: the built-in Tango) in the facility (--facility
    DIR, a facility folder; default: TRON as [testbed] describes it)."""
    return Request(saved=folders(target, facility))
