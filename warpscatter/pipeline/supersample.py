"""Camera anti-aliasing by supersampling: render at ``s`` times the width and height, then box-filter.

``camera.supersample: s`` gives each output pixel the mean of ``s x s`` rays on an ordered sub-pixel grid: sub-pixel
(a, b) of pixel (i, j) is pixel (s i + a, s j + b) of the s-times larger image (CONVENTIONS rays). Every method
renders that frame unchanged and the filter averages its blocks, so surfaces, shadows, depth, scattering and the ray
marchers' jitter are all anti-aliased, for about s^2 times the per-pixel work (the light's maps are unchanged).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np


def supersampled_scene(scene, s: int):
    """``scene`` with its camera's width and height multiplied by ``s`` (the scene itself when ``s`` is 1)."""
    if s == 1:
        return scene
    cam = scene.camera
    return replace(scene, camera=replace(cam, width=cam.width * s, height=cam.height * s))


def box_filter(images: dict[str, np.ndarray], s: int, frame: tuple[int, int]) -> dict[str, np.ndarray]:
    """Average the ``s x s`` blocks (float32) of every image of size ``frame`` = (height, width), ``depth`` too (at a
    silhouette it lies between the sub-samples' distances); images of other sizes (light-space debug) pass as is."""
    if s == 1:
        return images
    out = {}
    for name, img in images.items():
        h, w = frame
        if img.shape[:2] != (h, w):
            out[name] = img
            continue
        total = np.zeros((h // s, w // s, *img.shape[2:]), np.float32)
        for a in range(s):  # s^2 strided views added (float32): several times faster than a mean over block axes
            for b in range(s):
                total += img[a::s, b::s]
        out[name] = total * np.float32(1.0 / (s * s))
    return out


__all__ = ["box_filter", "supersampled_scene"]
