"""Single scattering in homogeneous media: the ray-marching reference and the fast techniques.

* :mod:`.raymarch` — per-pixel ray marching with shadow-map or exact (ray-cast) visibility, the
  ground truth every other method is measured against.
* :mod:`.rectify`, :mod:`.rectify_projective` — rectified shadow maps (Peters 2017 non-linear, Klehm 2014
  projective).
* :mod:`.prefilter`, :mod:`.prefiltered` — prefiltered single scattering with a Fourier basis (Klehm 2014)
  or moments (Peters 2017 Sec. 5).
* :mod:`.epipolar_lines`, :mod:`.epipolar` — epipolar sampling (Engelhardt & Dachsbacher 2010).
"""
