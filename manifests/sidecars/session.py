"""``W/session.json``: what acquire recorded about the capture session (docs/architecture.md
section 4). Written by acquire; read by calibrate, and by label and render for the mock-up
scale."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.sidecars.base import SidecarError, read, save
from manifests.workspace import Workspace

SESSION_VERSION = 1
BACKENDS = ("virtual", "replay")
FORMATS = ("virtual", "session", "handeye", "tabb")
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
    def from_json(cls, data: Any, where: str) -> Session:
        """Validated; errors start with ``where`` (the file) and name the key."""
        def fail(key: str, expected: str) -> SidecarError:
            value = data.get(key) if isinstance(data, dict) else data
            return SidecarError(f"{where}: key {key}: expected {expected}, got {value!r}")

        if not isinstance(data, dict):
            raise SidecarError(f"{where}: expected a JSON object")
        if data.get("version") != SESSION_VERSION:
            raise SidecarError(f"{where}: version {data.get('version')!r}, this program reads version "
                               f"{SESSION_VERSION}; rerun acquire with --force")
        unknown = sorted(set(data) - {"version", "backend", "format", "source", "sources", "pattern", "camera",
                                      "frames", "mockup_scale"})
        if unknown:
            raise SidecarError(f"{where}: unknown key(s) {', '.join(unknown)}")
        if data.get("backend") not in BACKENDS:
            raise fail("backend", " or ".join(BACKENDS))
        if data.get("format") not in FORMATS:
            raise fail("format", ", ".join(FORMATS))
        sources = data.get("sources")
        if not isinstance(sources, list) or not sources or sources[0] != "kuka" or not set(sources) <= set(SOURCES):
            raise fail("sources", 'a list starting with "kuka", optionally "vicon"')
        camera = data.get("camera")
        if (not isinstance(camera, dict) or not all(isinstance(camera.get(k), int) and camera[k] > 0
                                                    for k in ("width", "height"))):
            raise fail("camera", "an object with positive integer width and height")
        matrix, dist = camera.get("K"), camera.get("dist")
        if matrix is not None and (not isinstance(matrix, list) or len(matrix) != 3
                                   or not all(isinstance(r, list) and len(r) == 3 for r in matrix)):
            raise fail("camera", "K as a 3 x 3 list, or null")
        if dist is not None and (not isinstance(dist, list) or not all(isinstance(v, int | float) for v in dist)):
            raise fail("camera", "dist as a list of numbers, or null")
        pattern = data.get("pattern")
        if pattern is not None and (not isinstance(pattern, dict) or "kind" not in pattern or "size" not in pattern):
            raise fail("pattern", "a pattern object (kind, size, square_m, ...) or null")
        for key, kind in (("source", str), ("frames", dict), ("mockup_scale", int | float)):
            if data.get(key) is not None and not isinstance(data[key], kind):
                raise fail(key, f"{getattr(kind, '__name__', 'a number')} or null")
        return cls(data["backend"], data["format"], tuple(sources),
                   SessionCamera(camera["width"], camera["height"], matrix, dist), pattern, data.get("source"),
                   data.get("frames"), None if data.get("mockup_scale") is None else float(data["mockup_scale"]))


def write_session(workspace: Workspace, session: Session) -> None:
    save(workspace.session_path, session.to_json())


def read_session(workspace: Workspace) -> Session:
    """``W/session.json``, validated; a SidecarError that names the file and says what to rerun."""
    return read(workspace.session_path, SESSION_VERSION, "acquire", lambda f: Session.from_json(f.data, f.where))
