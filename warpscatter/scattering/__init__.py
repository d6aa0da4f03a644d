"""Single scattering in homogeneous media: the ray-marching reference and the fast techniques.

* :mod:`.settings` — the Warp-free settings of ``render.scattering``; :mod:`.marching` — the shared estimator;
* :mod:`.raymarch` — per-pixel ray marching, with exact visibility the ground truth of every other method;
* :mod:`.sparse_evaluation` — a per-pixel look-up on a grid and the pixels the grid cannot interpolate;
* :mod:`.rectify` — rectified shadow maps (Peters 2017 non-linear, Klehm 2014 projective), caster culling;
* :mod:`.prefiltered` — Fourier (Klehm 2014) or moment (Peters 2017 Sec. 5) prefiltered single scattering;
* :mod:`.epipolar` — epipolar sampling (Engelhardt & Dachsbacher 2010).
"""
