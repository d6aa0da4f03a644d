"""Epipolar sampling for crepuscular rays (Engelhardt & Dachsbacher 2010): the ``epipolar`` render method.

* :mod:`.method` — :func:`render`, the method's stages;
* :mod:`.lines` — the epipolar lines on the screen (host geometry, Sec. 4.1, 5.1);
* :mod:`.textures` — the lines on the device: coordinate and depth textures, the discontinuity search (Sec. 5.1-5.2);
* :mod:`.upsampling` — interpolation along the lines and bilateral upsampling to every pixel (Sec. 4.3, 5.3).
"""

from .method import render

__all__ = ["render"]


def __getattr__(name: str):
    from ...moved import moved_attribute

    return moved_attribute(__name__, "warpscatter.scattering.epipolar.method", name)
