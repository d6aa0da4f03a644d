"""Rectified shadow maps for prefiltered single scattering: every camera view ray in one row, along the columns, at
one depth (Klehm 2014 Sec. 3.2, 4.2; Peters 2017 Sec. 5.1.1, 5.2, App. A).

Modules: :mod:`.spherical` (the non-linear coordinates in kernels), :mod:`.bounds` (their per-frame bounds),
:mod:`.taps` (resample taps, two-depth split), :mod:`.nonlinear` (resampling a directional light's map), :mod:`.local`
(a spot light's rectification), :mod:`.projective` (Klehm's, rasterized straight into the map), :mod:`.reference_rays`
(one reference view ray per row) and :mod:`.params` (either map in kernels, the per-frame choice). Layers:
spherical <- bounds <- reference_rays, projective; spherical <- taps <- nonlinear, local.
"""
