"""Single scattering in homogeneous media: the ray-marching reference and the fast techniques.

* :mod:`.settings` — the Warp-free settings of ``render.scattering`` (every method's keys, defaults, ranges).
* :mod:`.marching` — the marching estimator every marching method shares (``Marcher``, ``march_ray``, ...).
* :mod:`.raymarch` — the ``raymarch`` method: per-pixel ray marching with shadow-map or exact (ray-cast)
  visibility, the ground truth every other method is measured against.
* :mod:`.sparse_evaluation` — a per-pixel look-up on a grid and the pixels the grid cannot interpolate (epipolar and
  prefiltered).
* :mod:`.rectify` — rectified shadow maps (Peters 2017 non-linear, Klehm 2014 projective, spot lights), the
  per-frame choice between them and caster culling.
* :mod:`.prefiltered` — prefiltered single scattering with a Fourier basis (Klehm 2014) or moments (Peters 2017
  Sec. 5): the bases and per-row prefix sums, the per-pixel look-ups, the method's passes.
* :mod:`.epipolar` — epipolar sampling (Engelhardt & Dachsbacher 2010).
"""
