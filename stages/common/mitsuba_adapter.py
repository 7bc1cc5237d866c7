"""The one module that calls Mitsuba 3 and Dr.Jit (docs/architecture.md section 3; a test
holds every other module to it), used by the virtual testbed's camera, the synthetic twins
and the training set: loading the LLVM variant (an error naming what to install when it is
missing: there is no fallback) and a per-process kernel cache, the thread split, the sensor
built from a pinhole ``RenderGeometry``, the camera pose through ``OPENCV_FROM_MITSUBA``,
meshes and BSDFs from dictionaries (``bsdf``), deterministic scene loading, the loaded
scene's parameters and rendering (``LoadedScene``: load, set the camera, transforms, lights
and vertices, render), and ray casts (silhouettes, surface hits).

Mitsuba is imported here lazily, so that stages which never render never load it.
"""

from __future__ import annotations

import os
import socket
from typing import Any, Literal

import numpy as np

from speedplus.errors import InputError
from stages.common.lens import RenderGeometry

#: Mitsuba's camera frame in OpenCV's (``opencv_from_mitsuba``): both look along +z, but
#: Mitsuba's x points left and y up where OpenCV's x points right and y down. A sensor's
#: ``to_world`` is ``world_from_cam @ OPENCV_FROM_MITSUBA`` (the matrix is its own inverse;
#: the name says which way it is used).
OPENCV_FROM_MITSUBA = np.diag([-1.0, -1.0, 1.0, 1.0])


_CACHE_LOCKS: list[int] = []
#: cache slots per host: more renderers than this on one host compile into temporary caches
CACHE_SLOTS = 256
#: the variant every renderer should use; a Ray worker that would use another is refused
PREFERRED_VARIANT = "llvm_ad_rgb"


def _interruptible(render: Any) -> np.ndarray:
    """The film of ``render()`` as numpy. Dr.Jit wraps an exception raised inside its custom
    operation (Mitsuba's render) in a RuntimeError: a Ctrl-C that lands mid-render, in a
    process that renders itself (``run.workers = 1``), is given back as the
    KeyboardInterrupt it was, which the command reports as an interruption, not a bug."""
    try:
        return np.array(render())
    except RuntimeError as error:
        cause = error.__cause__ or error.__context__
        while cause is not None and not isinstance(cause, KeyboardInterrupt):
            cause = cause.__cause__ or cause.__context__
        if cause is None:
            raise
        raise KeyboardInterrupt from None


def private_kernel_cache() -> None:
    """Give this process a Dr.Jit kernel cache of its own (before Dr.Jit is imported).

    Worker processes compiling at the same time never write one cache file at once: each
    takes the first free cache slot of its host (an flock held for its lifetime, released
    even when it is killed) and reuses it in later runs. Slots are kept per host name, as
    many cluster nodes may share one home directory (where flock is not to be trusted across
    hosts); a process that finds no free slot compiles into a temporary cache of its own.
    """
    if "DRJIT_CACHE_DIR" in os.environ:
        return
    import fcntl
    import socket
    import tempfile
    from pathlib import Path

    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "speedplus" / "drjit"
    for slot in range(CACHE_SLOTS):
        directory = base / socket.gethostname() / f"slot-{slot}"
        try:
            directory.mkdir(parents=True, exist_ok=True)
            handle = os.open(directory / ".lock", os.O_CREAT | os.O_RDWR)
        except OSError:
            break  # a read-only or full home: fall through to a private cache
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(handle)
            continue
        _CACHE_LOCKS.append(handle)
        os.environ["DRJIT_CACHE_DIR"] = str(directory)
        return
    os.environ["DRJIT_CACHE_DIR"] = tempfile.mkdtemp(prefix="speedplus-drjit-")


def load_mitsuba() -> Any:
    """Mitsuba with the LLVM variant. Without a usable libLLVM it is an error saying what to
    install: the scenes here are built from arrays, which ``scalar_rgb`` cannot load (and it
    would render about 25x slower, with other noise)."""
    private_kernel_cache()
    import mitsuba as mi

    if not os.environ.get("DRJIT_LIBLLVM_PATH"):
        for candidate in ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"):
            if os.path.exists(candidate):
                os.environ["DRJIT_LIBLLVM_PATH"] = candidate
                break
    try:
        mi.set_variant(PREFERRED_VARIANT)
    except Exception as error:  # noqa: BLE001 - any failure of the LLVM backend means the same
        raise InputError(f"Mitsuba's {PREFERRED_VARIANT} variant is unavailable on {socket.gethostname()} "
                         f"({' '.join(str(error).split())[:200]}); install Debian libllvm19 (make setup does, as "
                         "root) or point DRJIT_LIBLLVM_PATH at a libLLVM >= 16") from None
    # Mitsuba's own warnings ("Received interrupt signal, winding down" on Ctrl-C) are not a
    # user's business: the runner says what was kept; errors still surface as exceptions
    mi.set_log_level(mi.LogLevel.Error)
    return mi


def mitsuba_variant() -> dict[str, str]:
    """What a render worker reports to the engine before it takes an item (``core.engines.cluster``)."""
    return {"mitsuba_variant": load_mitsuba().variant()}


def set_one_thread() -> None:
    """One Dr.Jit thread for this process, whatever the engine reserved: the testbed runs as
    many workers as cores instead, which keeps the cores as busy, and a capture's pixels
    never depend on a thread count (samples of one pixel added from several threads may
    be summed in another order)."""
    import drjit as dr

    dr.set_thread_count(1)


def set_threads(threads: int) -> None:
    """Dr.Jit's thread count for this process: ``threads``, or in a Ray worker the CPUs Ray
    reserved for it. A twin's pixels do not depend on it (``LoadedScene.render_window``
    sums each pixel in one lane; tests/stages/common/test_windows.py)."""
    import drjit as dr

    from core.engines import reserved_cpus

    dr.set_thread_count(max(1, reserved_cpus(threads)))


def sensor(mi: Any, geometry: RenderGeometry, *, far_clip_m: float, pixel_format: Literal["rgb", "rgba"],
           sampler: Literal["independent", "multijitter"] = "independent") -> dict[str, Any]:
    """A perspective sensor of the pinhole ``geometry`` (centred principal point, square
    pixels), posed later by ``sensor_to_world``. Its box filter puts a sample in its own
    pixel only: alpha is exact coverage, and no sample is splatted onto neighbours (a blur,
    where wanted, is applied to the film after: ``stages/acquire/virtual/scene.py``).
    ``multijitter`` stratifies each pixel's samples on a jittered grid (Kensler, "Correlated
    Multi-Jittered Sampling", Pixar 2013), ``independent`` draws them uniformly."""
    return {
        "type": "perspective",
        "fov_axis": "x",
        "fov": float(np.degrees(geometry.fov_x_rad)),
        "near_clip": 0.05,
        "far_clip": far_clip_m,
        "to_world": sensor_to_world(mi, np.eye(4)),
        "film": {"type": "hdrfilm", "width": geometry.width, "height": geometry.height, "rfilter": {"type": "box"},
                 "pixel_format": pixel_format},
        "sampler": {"type": sampler},
    }


def sensor_to_world(mi: Any, world_from_cam: np.ndarray) -> Any:
    """The sensor's ``to_world`` for an OpenCV camera at ``world_from_cam`` (4, 4)."""
    return transform(mi, np.asarray(world_from_cam, float) @ OPENCV_FROM_MITSUBA)


def transform(mi: Any, matrix: np.ndarray) -> Any:
    """A Mitsuba transform of a (4, 4) matrix."""
    return mi.ScalarTransform4f(np.asarray(matrix, dtype=float).tolist())


def mesh(mi: Any, name: str, vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, bsdf: Any) -> Any:
    """A triangle mesh: vertices (V, 3) m, faces (F, 3), texture coordinates (V, 2)."""
    props = mi.Properties()
    props["bsdf"] = bsdf
    shape = mi.Mesh(name, len(vertices), len(faces), props=props, has_vertex_normals=False,
                    has_vertex_texcoords=True)
    params = mi.traverse(shape)
    params["vertex_positions"] = mi.Float(np.asarray(vertices, np.float32).ravel())
    params["faces"] = mi.UInt32(np.asarray(faces, np.uint32).ravel())
    params["vertex_texcoords"] = mi.Float(np.asarray(uv, np.float32).ravel())
    params.update()
    return shape


def load_scene(mi: Any, objects: dict[str, Any]) -> Any:
    """``mi.load_dict`` with the shapes and emitters in the dictionary's order.

    Mitsuba's default (parallel, optimised) loading orders them differently from one
    process to the next; the emitter order decides which random number picks which light,
    so the same seed would give different noise in different workers.
    """
    return mi.load_dict(objects, parallel=False, optimize=False)


def rays(mi: Any, origins: np.ndarray, directions: np.ndarray) -> Any:
    """Mitsuba rays from origins (N, 3) or (3,) along directions (N, 3), in the scene's frame."""
    origins = np.broadcast_to(np.asarray(origins, float), np.shape(directions))
    return mi.Ray3f(mi.Point3f(*[np.ascontiguousarray(origins[:, i], np.float32) for i in range(3)]),
                    mi.Vector3f(*[np.ascontiguousarray(directions[:, i], np.float32) for i in range(3)]))


def first_hit_on(mi: Any, scene: Any, ray_batch: Any, shape_ids: set[str] | None = None) -> np.ndarray:
    """(N,) bool: whether each ray's first surface is one of ``shape_ids`` (any shape when
    None). Ray-cast silhouettes: independent of films, filters and sampling noise."""
    import drjit as dr

    hit = scene.ray_intersect(ray_batch)
    if shape_ids is None:
        return np.array(hit.is_valid(), dtype=bool)
    on = dr.zeros(mi.Bool, dr.width(ray_batch.o))
    for shape in scene.shapes():
        if shape.id() in shape_ids:
            on |= hit.is_valid() & (hit.shape == mi.ShapePtr(shape))
    return np.array(on, dtype=bool)


def sensor_pixel_rays(mi: Any, scene: Any, geometry: RenderGeometry) -> Any:
    """The scene's sensor's rays through the centre of every pixel of ``geometry``, row by row."""
    width, height = geometry.width, geometry.height
    ys, xs = np.mgrid[0:height, 0:width]
    position = mi.Point2f(((xs.ravel() + 0.5) / width).astype(np.float32),
                          ((ys.ravel() + 0.5) / height).astype(np.float32))
    ray_batch, _ = scene.sensors()[0].sample_ray(0.0, 0.0, position, mi.Point2f(0.5, 0.5))
    return ray_batch


def bsdf(mi: Any, spec: dict[str, Any]) -> Any:
    """A BSDF from its Mitsuba dictionary ``spec``, in which every ``bitmap`` given as an array
    (H, W, C) becomes a Mitsuba bitmap (``stages.common.looks`` describes looks as such
    dictionaries, without Mitsuba)."""
    return mi.load_dict(_with_bitmaps(mi, spec))


def _with_bitmaps(mi: Any, spec: dict[str, Any]) -> dict[str, Any]:
    return {key: mi.Bitmap(value) if key == "bitmap" and isinstance(value, np.ndarray)
            else _with_bitmaps(mi, value) if isinstance(value, dict) else value for key, value in spec.items()}


def surface_hits(mi: Any, scene: Any, origins: np.ndarray, directions: np.ndarray, shape_index: dict[str, int],
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first surface of each ray (origins (3,) or (N, 3), directions (N, 3), the scene's
    frame): the index ``shape_index`` gives its shape (N,) uint8 (0: no shape of it), the
    hit point (N, 3) and the surface normal (N, 3), float64 (meaningful where hit)."""
    import drjit as dr

    hit = scene.ray_intersect(rays(mi, origins, directions))
    part = dr.zeros(mi.UInt32, len(directions))
    for shape in scene.shapes():
        if shape.id() in shape_index:
            part = dr.select(hit.is_valid() & (hit.shape == mi.ShapePtr(shape)), shape_index[shape.id()], part)
    # one kernel for every output: evaluated one by one, each compiled a kernel of its own
    # (0.15 s a cast, as long as the cast)
    dr.eval(part, hit.p, hit.n)
    points = np.stack([np.array(hit.p[i], dtype=np.float64) for i in range(3)], 1)
    normals = np.stack([np.array(hit.n[i], dtype=np.float64) for i in range(3)], 1)
    return np.array(part, dtype=np.uint8), points, normals


class LoadedScene:
    """A scene loaded from its dictionary (``load_scene``) and the one way the project changes
    and renders it, as kubric's ``View`` keeps its renderer: the camera, transforms, colours,
    scalars and vertex positions set by key, then ``render`` with the keys that must stay
    opaque (one compiled kernel whatever their values: the noise never depends on which
    capture compiled it)."""

    def __init__(self, mi: Any, objects: dict[str, Any]) -> None:
        self.mi = mi
        self.scene = load_scene(mi, objects)
        self._params = mi.traverse(self.scene)

    def keys(self) -> list[str]:
        """Every parameter's key (``shape.vertex_positions``, ``sensor.to_world``, ...)."""
        return list(self._params.keys())

    def set_camera(self, world_from_cam: np.ndarray) -> None:
        """The sensor's pose (4, 4), OpenCV camera axes."""
        self._params["sensor.to_world"] = sensor_to_world(self.mi, world_from_cam)

    def set_transform(self, key: str, matrix: np.ndarray) -> None:
        """A ``to_world`` (4, 4)."""
        self._params[key] = transform(self.mi, matrix)

    def set_grey(self, key: str, value: float) -> None:
        """An RGB parameter (a radiance, an irradiance) to ``value`` in all three channels."""
        self._params[key] = self.mi.Color3f(value, value, value)

    def set_scalar(self, key: str, value: float) -> None:
        self._params[key] = value

    def set_vertices(self, key: str, vertices: np.ndarray) -> None:
        """A mesh's vertex positions (N, 3), stored as float32."""
        self._params[key] = self.mi.Float(np.asarray(vertices).astype(np.float32).ravel())

    def update(self) -> None:
        """Apply what was set (before a ray cast; ``render`` does it itself)."""
        self._params.update()

    def render_window(self, x: int, y: int, width: int, height: int, spp: int, seed: int,
                      opaque: tuple[str, ...] | list[str] = ()) -> np.ndarray:
        """The pixels (height, width, 4) of the window (``x``, ``y``, ``width``, ``height``) px of
        the scene's sensor's film, RGB and alpha (the share of samples that hit), as its box
        filter would hold them: each pixel the mean of ``spp`` samples drawn uniformly in it,
        through the sensor's own rays, traced by the scene's integrator. For the target's
        sensor (``sensor``: independent sampler, box filter, no crop, a pinhole).

        Mitsuba's own ``render`` of a film crop compiles the crop's size and offset into
        Dr.Jit's kernel (0.1-0.3 s at every new size); here the window and ``spp`` are
        opaque, so every window of every pose is one compiled kernel, which renders no pixel
        outside the window (docs/architecture.md section 7). One lane a pixel adds its samples
        in their order: the pixels are the same bits whatever the thread count (lanes of one
        pixel's samples, summed by atomic adds, differed with 2 threads where a small
        window's launch split a pixel between threads)."""
        import drjit as dr

        mi = self.mi
        for key in opaque:
            dr.make_opaque(self._params[key])
        self._params.update()
        sensor, integrator = self.scene.sensors()[0], self.scene.integrator()
        film = sensor.film()
        sampler_name, crop = sensor.sampler().class_name(), [int(v) for v in film.crop_size()]
        if sampler_name != "IndependentSampler" or crop != [int(v) for v in film.size()]:
            raise ValueError("render_window draws a whole film's pixels with independent samples; this sensor "
                             f"has a {sampler_name} and a crop of {crop}")
        film_size = mi.ScalarVector2f(*(float(v) for v in film.size()))
        left, top, columns, samples, seed_value = (mi.UInt32(v) for v in (x, y, width, spp, seed))
        dr.make_opaque(left, top, columns, samples, seed_value)
        pixel = dr.arange(mi.UInt32, width * height)
        row = pixel // columns
        corner = mi.Vector2f(mi.Float(left + pixel - row * columns), mi.Float(top + row))
        sampler = sensor.sampler().clone()
        sampler.seed(seed_value, width * height)

        def one_sample(index: Any, rgb: Any, hits: Any, sampler: Any) -> tuple[Any, Any, Any, Any]:
            position = corner + sampler.next_2d()  # uniform in the pixel: the box filter
            ray, weight = sensor.sample_ray(0.0, 0.0, position / film_size, mi.Point2f(0.5, 0.5))
            spectrum, valid, _ = integrator.sample(self.scene, sampler, ray)
            return index + 1, rgb + spectrum * weight, hits + dr.select(valid, 1.0, 0.0), sampler

        _, rgb, hits, _ = dr.while_loop(state=(mi.UInt32(0), mi.Color3f(0.0), mi.Float(0.0), sampler),
                                        cond=lambda index, *_: index < samples, body=one_sample)

        def develop() -> np.ndarray:
            dr.eval(rgb, hits)
            return np.stack([np.asarray(rgb[0]), np.asarray(rgb[1]), np.asarray(rgb[2]), np.asarray(hits)],
                            axis=-1).astype(np.float32)

        return (_interruptible(develop) * np.float32(1.0 / spp)).reshape(height, width, 4)

    def render(self, spp: int, seed: int, opaque: tuple[str, ...] | list[str] = ()) -> np.ndarray:
        """The film (H, W, C) as numpy, after making ``opaque`` keys opaque and applying what
        was set."""
        import drjit as dr

        for key in opaque:
            dr.make_opaque(self._params[key])
        self._params.update()
        return _interruptible(lambda: self.mi.render(self.scene, spp=spp, seed=seed))
