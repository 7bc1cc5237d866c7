"""The looks of a target's parts as Mitsuba 3 BSDF dictionaries (``manifests.target.LOOK_PRESETS``;
bitmaps as arrays, which ``mitsuba_adapter.bsdf`` loads: no Mitsuba call here):
each preset has the flight model's ideal look, which the renderer gives the synthetic
twin, and the physical mock-up's, which the virtual testbed photographs. Their difference
is the domain gap the paper measures, so a mock-up look is never the synthetic one:

============  ==========================================  ==========================================
preset        synthetic (render)                          mock-up (virtual testbed)
============  ==========================================  ==========================================
gold_mli      smooth gold foil: rough gold conductor      crumpled foil: a brighter, rougher blend
              blended with a 25% diffuse gold             under a normal map of wrinkles
solar_cells   a regular cell grid under cover glass       printed cells of uneven tint, glossier
aluminium     brushed aluminium (roughness 0.2)           polished plate (0.09) with rivets, seams
                                                          and handling smudges
white_paint   white radiator paint, reflectance 0.8       grey-white paint, 0.55
black_paint   black paint, 0.04                           matt black, 0.07
rock          one grey-brown, 0.3 / 0.27 / 0.24           a painted replica, mottled and grainy
============  ==========================================  ==========================================

A part without a look renders with the mesh's own colour (glTF base colour, MTL ``Kd``
or its vertex colours; mid grey when it has none) on the twin, and white paint on the
mock-up. Textures come from ``stages.common.textures``; the mock-up's are drawn from the
random stream the caller passes, part after part in the mesh's order.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from manifests.target import Look
from stages.common import textures

MESH_DEFAULT_GREY = (0.5, 0.5, 0.5)


def _rgb(value: Any) -> dict[str, Any]:
    return {"type": "rgb", "value": [float(v) for v in value]}


def synthetic_look(look: Look | None, colour: tuple[float, float, float] | None) -> dict[str, Any]:
    """The twin's BSDF of a part with ``look`` (None: its mesh ``colour``, linear RGB)."""
    preset = None if look is None else look.synthetic
    if preset == "gold_mli":  # multi-layer insulation: gold foil, a rough conductor, evenly stretched
        return {"type": "blendbsdf", "weight": 0.25,
                "bsdf_0": {"type": "roughconductor", "material": "Au", "alpha": 0.35},
                "bsdf_1": {"type": "diffuse", "reflectance": _rgb([0.55, 0.4, 0.12])}}
    if preset == "solar_cells":
        return {"type": "roughplastic", "alpha": 0.06, "int_ior": 1.5,
                "diffuse_reflectance": {"type": "bitmap", "bitmap": textures.clean_solar_cells()}}
    if preset == "white_paint":
        return {"type": "diffuse", "reflectance": _rgb([0.8, 0.8, 0.8])}
    if preset == "aluminium":
        return {"type": "roughconductor", "material": "Al", "alpha": 0.2}
    if preset == "black_paint":
        return {"type": "diffuse", "reflectance": _rgb([0.04, 0.04, 0.04])}
    if preset == "rock":
        return {"type": "diffuse", "reflectance": _rgb([0.3, 0.27, 0.24])}
    if preset is not None:
        raise ValueError(f"unknown look {preset!r}")  # manifests.target refuses it on read
    return {"type": "diffuse", "reflectance": _rgb(colour or MESH_DEFAULT_GREY)}


def mockup_look(look: Look | None, rng: np.random.Generator) -> dict[str, Any]:
    """The mock-up's BSDF of a part with ``look`` (None: white paint); textures from ``rng``."""
    preset = "white_paint" if look is None else look.mockup
    if preset == "gold_mli":  # crumpled MLI: a rough gold mirror with a diffuse share from the creases
        inner = {"type": "blendbsdf", "weight": 0.35,
                 "bsdf_0": {"type": "roughconductor", "material": "Au", "alpha": 0.25},
                 "bsdf_1": {"type": "diffuse", "reflectance": _rgb([0.75, 0.6, 0.3])}}
        return {"type": "normalmap", "bsdf": inner,
                "normalmap": {"type": "bitmap", "raw": True, "bitmap": textures.foil_normal_map(rng)}}
    if preset == "solar_cells":
        return {"type": "roughplastic", "alpha": 0.04, "int_ior": 1.5,
                "diffuse_reflectance": {"type": "bitmap", "bitmap": textures.solar_cells(rng)}}
    if preset == "aluminium":
        return {"type": "roughconductor", "material": "Al", "alpha": 0.09,
                "specular_reflectance": {"type": "bitmap", "bitmap": textures.rear_panel(rng)}}
    if preset == "white_paint":
        return {"type": "diffuse", "reflectance": _rgb([0.55, 0.55, 0.55])}
    if preset == "black_paint":
        return {"type": "diffuse", "reflectance": _rgb([0.07, 0.07, 0.07])}
    if preset == "rock":
        return {"type": "diffuse", "reflectance": {"type": "bitmap", "bitmap": textures.mottled_rock(rng)}}
    raise ValueError(f"unknown look {preset!r}")  # manifests.target refuses it on read
