"""Files and configs that several test modules build (not a test module: pytest collects only ``test_*.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio

#: A small animated config: a fence under a turning sun, three raymarched frames of 24 x 14.
ANIMATED = {
    "scene": {"meshes": [{"procedural": "ground_plane", "params": {"size": 30}, "receiver_only": True},
                         {"procedural": "fence", "transform": {"translate": [0, 0, 3]}}]},
    "camera": {"position": [0, 2, -8], "look_at": [0, 1, 3], "width": 24, "height": 14},
    "light": {"type": "directional", "direction": [0.6, -0.4, 1.0]},
    "medium": {"sigma_t": 0.1, "albedo": 0.9},
    "render": {"scattering": {"method": "raymarch", "visibility": "shadow_map", "steps": 8,
                              "shadow_map": {"resolution": 64}}},
    "output": {"name": "{config}", "aovs": ["color", "depth"]},
    "animation": {"frames": 3, "preview": "none",
                  "tracks": {"light.direction": {1: [0.6, -0.4, 1.0], 3: [-0.6, -0.4, 1.0]}}},
}


def raw_exr(path: Path, pixels) -> Path:
    """An EXR holding exactly ``pixels`` (H, W, C) (NaN, inf, negative: warpscatter.io.images refuses to write
    those)."""
    pixels = np.asarray(pixels, np.float32)
    h, w, c = pixels.shape
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(w, h, c, "float"))
    assert out.write_image(pixels)
    out.close()
    return path
