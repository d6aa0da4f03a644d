"""Single scattering in homogeneous media: the ray-marching reference and the fast techniques.

* :mod:`.raymarch` — per-pixel ray marching with shadow-map or exact (ray-cast) visibility, the
  ground truth every other method is measured against.
* :mod:`.rectify`, :mod:`.prefilter` — rectified shadow maps and prefiltered visibility (Klehm 2014).
"""
