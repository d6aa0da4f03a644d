"""Rectified shadow maps for prefiltered single scattering: every camera view ray in one row, along the columns, at
one depth (Klehm 2014 Sec. 3.2, 4.2; Peters 2017 Sec. 5.1.1, 5.2, App. A).

* :mod:`.spherical` -- the non-linear (spherical) coordinates as kernels see them;
* :mod:`.bounds` -- their bounds for one camera and a directional light (host, Peters 2017 App. A);
* :mod:`.taps` -- the resample taps and the two-depth tap split, shared by every resampled map;
* :mod:`.nonlinear` -- resampling a directional light's shadow map (nearest, supersampled, moment-filtered);
* :mod:`.local` -- the rectification of a spot light and its resampling with an emission filter (Klehm Sec. 3.2);
* :mod:`.projective` -- Klehm's projective rectification, rasterized straight into the map (Sec. 4.2);
* :mod:`.reference_rays` -- one reference view ray per row, for both kinds (Klehm Sec. 3.2).

Layers: spherical <- bounds <- reference_rays; spherical <- taps <- nonlinear, local; bounds <- projective.
"""
