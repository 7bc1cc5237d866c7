"""``W/session.json``: what acquire recorded about the capture session (docs/architecture.md
section 4). Written by acquire; read by calibrate, and by label and render for the mock-up
scale."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.sidecars.base import Fields, read, save
from manifests.workspace import Workspace

SESSION_VERSION = 1
BACKENDS = ("virtual", "replay")
FORMATS = ("virtual", "session", "handeye", "tabb", "rosbag")
SOURCES = ("kuka", "vicon")


@dataclass(frozen=True)
class SessionCamera:
    """The camera of the captures: size (px) and, when known, K (3 x 3, px) and OpenCV's
    distortion coefficients; unknown intrinsics are estimated by calibrate."""

    width: int
    height: int
    camera_matrix: list[list[float]] | None = None
    dist: list[float] | None = None

    def to_json(self) -> dict[str, Any]:
        return {"K": self.camera_matrix, "dist": self.dist, "width": self.width, "height": self.height}


@dataclass(frozen=True)
class Session:
    """``W/session.json``: what acquire recorded about the capture session."""

    backend: str  # one of BACKENDS
    format: str  # one of FORMATS ("virtual" for the virtual testbed)
    sources: tuple[str, ...]  # measurement sources, "kuka" first
    camera: SessionCamera
    pattern: dict[str, Any] | None  # a PatternSpec's JSON (stages.common.patterns); None: no pattern
    source: str | None = None  # replay: the recorded folder
    frames: dict[str, str] | None = None  # replay: what camee, targetee, world and target are
    mockup_scale: float | None = None  # virtual: model scale (full-scale translation = mock-up / scale)

    def to_json(self) -> dict[str, Any]:
        return {"version": SESSION_VERSION, "backend": self.backend, "format": self.format,
                "source": self.source, "sources": list(self.sources), "pattern": self.pattern,
                "camera": self.camera.to_json(), "frames": self.frames, "mockup_scale": self.mockup_scale}

    @classmethod
    def from_fields(cls, f: Fields) -> Session:
        """Validated; errors name the file and the key."""
        f.only("version", "backend", "format", "source", "sources", "pattern", "camera", "frames", "mockup_scale")
        sources = f.raw("sources")
        if not isinstance(sources, list) or not sources or sources[0] != "kuka" or not set(sources) <= set(SOURCES):
            raise f.fail("sources", 'a list starting with "kuka", optionally "vicon"')
        camera = f.child("camera")
        camera.only("K", "dist", "width", "height")
        matrix = [list(row) for row in camera.matrix("K", 3, 3)] if camera.optional("K") else None
        dist = list(camera.vector("dist")) if camera.optional("dist") else None
        pattern = f.child("pattern").data if f.optional("pattern") else None
        if pattern is not None and ("kind" not in pattern or "size" not in pattern):
            raise f.fail("pattern", "a pattern object (kind, size, square_m, ...) or null")
        frames = f.child("frames").data if f.optional("frames") else None
        return cls(f.text("backend", BACKENDS), f.text("format", FORMATS), tuple(sources),
                   SessionCamera(camera.integer("width", minimum=1), camera.integer("height", minimum=1), matrix,
                                 dist), pattern, f.text("source") if f.optional("source") else None, frames,
                   float(f.number("mockup_scale", positive=True)) if f.optional("mockup_scale") else None)


def write_session(workspace: Workspace, session: Session) -> None:
    save(workspace.session_path, session.to_json())


def read_session(workspace: Workspace) -> Session:
    """``W/session.json``, validated; a SidecarError that names the file and says what to rerun."""
    return read(workspace.session_path, SESSION_VERSION, "acquire", Session.from_fields)
