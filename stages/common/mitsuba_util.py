"""Mitsuba 3 shared by the virtual testbed and the synthetic twins: loading the fast
variant (with its fallback), a per-process kernel cache, meshes and transforms.

Mitsuba is imported here lazily, so that stages which never render never load it.
"""

from __future__ import annotations

import os
import warnings
from typing import Any

import numpy as np

#: Mitsuba's camera looks along +z with x to the left and y up; OpenCV's has x right, y down.
MITSUBA_FROM_OPENCV = np.diag([-1.0, -1.0, 1.0, 1.0])


_CACHE_LOCKS: list[int] = []


def private_kernel_cache() -> None:
    """Give this process a Dr.Jit kernel cache of its own (before Dr.Jit is imported).

    Worker processes compiling at the same time never write one cache file at once: each
    takes the first free cache slot (an flock held for its lifetime, released even when it
    is killed) and reuses it in later runs.
    """
    if "DRJIT_CACHE_DIR" in os.environ:
        return
    import fcntl
    from pathlib import Path

    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "speedplus" / "drjit"
    for slot in range(256):
        directory = base / f"slot-{slot}"
        directory.mkdir(parents=True, exist_ok=True)
        handle = os.open(directory / ".lock", os.O_CREAT | os.O_RDWR)
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(handle)
            continue
        _CACHE_LOCKS.append(handle)
        os.environ["DRJIT_CACHE_DIR"] = str(directory)
        return


def load_mitsuba() -> Any:
    """Mitsuba with the fast LLVM variant, or ``scalar_rgb`` (about 25x slower) with a warning."""
    private_kernel_cache()
    import mitsuba as mi

    if not os.environ.get("DRJIT_LIBLLVM_PATH"):
        for candidate in ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"):
            if os.path.exists(candidate):
                os.environ["DRJIT_LIBLLVM_PATH"] = candidate
                break
    try:
        mi.set_variant("llvm_ad_rgb")
    except Exception as error:  # noqa: BLE001 - any failure of the LLVM backend means: fall back
        warnings.warn(f"Mitsuba llvm_ad_rgb unavailable ({error}); rendering with the slow scalar_rgb variant. "
                      "Install Debian libllvm19 (make setup does, as root).", RuntimeWarning, stacklevel=2)
        mi.set_variant("scalar_rgb")
    return mi


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
