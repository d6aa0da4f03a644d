"""Single scattering in homogeneous media: the ray-marching reference and the fast techniques.

* :mod:`.settings` — the Warp-free settings of ``render.scattering`` (every method's keys, defaults, ranges).
* :mod:`.marching` — the marching estimator every marching method shares (``Marcher``, ``march_ray``, ...).
* :mod:`.raymarch` — the ``raymarch`` method: per-pixel ray marching with shadow-map or exact (ray-cast)
  visibility, the ground truth every other method is measured against.
* :mod:`.rectify_nonlinear`, :mod:`.rectify_projective`, :mod:`.rectification` — rectified shadow maps (Peters 2017
  non-linear, Klehm 2014 projective) and the per-frame choice between them.
* :mod:`.filtered_textures`, :mod:`.prefix_sums`, :mod:`.filtered_lookups`, :mod:`.caster_culling`,
  :mod:`.epipole_fallback`, :mod:`.prefiltered` — prefiltered single scattering with a Fourier basis (Klehm 2014) or
  moments (Peters 2017 Sec. 5): the bases and per-row prefix sums, the per-pixel look-ups, the method.
* :mod:`.epipolar_lines`, :mod:`.epipolar_textures`, :mod:`.epipolar_upsampling`, :mod:`.epipolar` — epipolar
  sampling (Engelhardt & Dachsbacher 2010).
"""
