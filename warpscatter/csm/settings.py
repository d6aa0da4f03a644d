"""Settings of the Monte-Carlo lighting methods and of coherent shadow maps (``render.lighting``; Warp-free, the one
place they are written): :class:`CSMBuildSettings` (Ritschel et al. 2007 Sec. 3-4) and :class:`LightingSettings`
(Sec. 5).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal, Optional

from pydantic import Field, ValidationInfo, field_validator

from .. import methods
from ..schema import MAX_COORD, Bool, Float, Int, PathStr, Seed, SettingsModel, existing_file, resolve_path

#: The option values of the fields below (their descriptions say what each means).
ENUMERATIONS = ("scanline", "zigzag", "hilbert")
DEPTH_LAYERS = ("z1z2", "z1z3")
FAR_MODES = ("sphere", "infinite")
FILTERS = ("nearest", "pcf", "roulette")
LOCAL_LIGHT_MODES = ("cube", "semi_local")
#: Limits of the build parameters.
MAX_MAP_GRID = 1024
MAX_LIGHT_SAMPLES = 256
MIN_RESOLUTION = 8
MAX_RESOLUTION = 4096
MAX_BATCH = 4096


CSM_OBJECTS = ("scene", "per_mesh")


class CSMBuildSettings(SettingsModel):
    """The coherent shadow map of the lighting methods: a ``file`` from ``warpscatter precompute`` (.npz), or built
    on the fly from the scene's occluders with these parameters."""

    file: Optional[PathStr] = Field(None, description="a precomputed CSM (.npz, checked against the scene); null: "
                                                      "built on the fly")
    maps: tuple[Annotated[Int, Field(ge=1, le=MAX_MAP_GRID)], Annotated[Int, Field(ge=1, le=MAX_MAP_GRID)]] = Field(
        (64, 32), description="lat-long grid N1 x N2 of map directions (environment and semi-local lights)")
    light_samples: tuple[Annotated[Int, Field(ge=1, le=MAX_LIGHT_SAMPLES)],
                         Annotated[Int, Field(ge=1, le=MAX_LIGHT_SAMPLES)]] = Field(
        (8, 8), description="cube-map points n1 x n2 on an area light (n1 on a linear light)")
    resolution: Annotated[Int, Field(ge=MIN_RESOLUTION, le=MAX_RESOLUTION, description="depth-map size M")] = 128
    enumeration: Literal[ENUMERATIONS] = Field(  # type: ignore[valid-type]
        "hilbert", description="order of the maps along the compressed sequence")
    layers: Literal[DEPTH_LAYERS] = Field(  # type: ignore[valid-type]
        "z1z2", description="depths kept per texel: first and second surface, or first and third (closed meshes)")
    far: Literal[FAR_MODES] = Field(  # type: ignore[valid-type]
        "sphere", description="far depth of texels without a second surface: the bounding sphere, or infinity")
    batch: Annotated[Int, Field(ge=1, le=MAX_BATCH, description="maps rendered and compressed per batch (memory ~ M^2 "
                                                                "x batch)")] = 64
    local_lights: Literal[LOCAL_LIGHT_MODES] = Field(  # type: ignore[valid-type]
        "cube", description="area / linear lights: depth cube maps at the light's samples (Sec. 4.2), or the "
                            "lat-long CSM queried towards each light point (semi-local, Sec. 4.3); a volume light is "
                            "always semi-local")
    objects: Literal[CSM_OBJECTS] = Field(  # type: ignore[valid-type]
        "scene", description="scene: one CSM of all occluders in world space; per_mesh: one lat-long CSM per casting "
                             "mesh in its own object space, placed by the mesh's transform (Sec. 4.6: moving a "
                             "mesh changes its transform, never its CSM; area / linear lights then need "
                             "local_lights: semi_local)")

    @field_validator("file")
    @classmethod
    def _check_file(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        if v is None:
            return v
        p = existing_file(resolve_path(v, info))
        if p.suffix != ".npz":
            raise ValueError(f"a CSM file from 'warpscatter precompute' ends in .npz, got {p.name}")
        return p


class LightingSettings(SettingsModel):
    """Monte-Carlo direct lighting (Ritschel et al. 2007 Sec. 5) of environment, area and linear lights: ``csm``
    (coherent shadow maps) or ``raytrace`` (wp.Mesh shadow rays, the reference); null: the classic pipeline."""

    method: Optional[Literal[tuple(methods.LIGHTING)]] = Field(  # type: ignore[valid-type]
        None, description="csm (coherent-shadow-map visibility), raytrace (shadow rays, the reference) or null (the "
                          "classic pipeline of render.scattering)")
    samples: Annotated[Int, Field(ge=1, le=65536, description="strata per pixel and pass, a perfect square (each: one "
                                                              "light and one BRDF sample)")] = 16
    passes: Annotated[Int, Field(ge=1, le=100000, description="progressive passes, averaged")] = 8
    seed: Seed = Field(0, description="base seed; pass k draws its own patterns")
    filter: Literal[FILTERS] = Field(  # type: ignore[valid-type]
        "roulette", description="CSM filter: nearest, pcf (4 maps x 4 texels) or roulette (one of those 16 picked "
                                "with its PCF weight, Sec. 4.5)")
    bias: Optional[Annotated[Float, Field(ge=0.0, le=MAX_COORD)]] = Field(
        None, description="CSM depth bias (scene units); null: one texel 2R/M of the occluders' bounding sphere")
    normal_offset: Optional[Annotated[Float, Field(ge=0.0, le=MAX_COORD)]] = Field(
        None, description="offset of the query point along the normal (scene units); null: R/(2M) for csm, 1e-4 x the "
                          "scene's diagonal for raytrace")
    write_every: Annotated[Int, Field(ge=0, le=100000, description="rewrite the outputs every this many passes (0: "
                                                                   "at the end only)")] = 1
    background: Bool = Field(True, description="show the environment map where nothing is hit")
    csm: CSMBuildSettings = Field(default_factory=dict, description="the coherent shadow map")

    @field_validator("samples")
    @classmethod
    def _square(cls, v: int) -> int:
        if math.isqrt(v) ** 2 != v:
            raise ValueError(f"must be a perfect square (a jittered s x s grid of strata), got {v}")
        return v

    @property
    def strata(self) -> int:
        """s of the s x s strata per pixel and pass."""
        return math.isqrt(self.samples)


__all__ = [
    "CSM_OBJECTS",
    "DEPTH_LAYERS",
    "ENUMERATIONS",
    "FAR_MODES",
    "FILTERS",
    "LOCAL_LIGHT_MODES",
    "CSMBuildSettings",
    "LightingSettings",
]
