"""Per-ray transmittance weights of the prefiltered look-ups (:mod:`warpscatter.scattering.prefiltered.ray_weights`)."""

import numpy as np
import pytest
import warp as wp

from warpscatter.scattering.prefiltered import filtered_lookups as fl
from warpscatter.scattering.prefiltered.ray_weights import RayWeights, ray_weights
from warpscatter.scattering.rectify.bounds import NonlinearRectification
from warpscatter.scattering.rectify.reference_rays import reference_ray
from warpscatter.scattering.settings import MAX_SEGMENTS, PrefilteredSettings
from warpscatter.scene.camera import Camera

ROWS, COLS = 8, 256


@wp.kernel
def lookup_kernel(weights: RayWeights, coords: wp.array(dtype=wp.vec3), wrap: int,
                  cols_out: wp.array2d(dtype=wp.int32), w_out: wp.array3d(dtype=wp.float32),
                  rows_out: wp.array2d(dtype=wp.int32)):
    n = wp.tid()
    c = coords[n]
    j0, j1, cut, m, i0, i1, ax, w0, w1 = fl.segment_lookup(weights, fl.whole_rows(ROWS, wrap), COLS, c[0], c[1], c[2])
    rows_out[n, 0] = j0
    rows_out[n, 1] = j1
    for k in range(wp.static(MAX_SEGMENTS + 2)):
        cols_out[n, k] = -1
    for k in range(m):
        cols_out[n, k] = cut[k]
        w_out[n, 0, k] = w0[k]
        w_out[n, 1, k] = w1[k]
    # the end: columns i0, i1 in slots m, m + 1
    cols_out[n, m] = i0
    cols_out[n, m + 1] = i1
    w_out[n, 0, m] = w0[m] * (1.0 - ax)
    w_out[n, 1, m] = w1[m] * (1.0 - ax)
    w_out[n, 0, m + 1] = w0[m] * ax
    w_out[n, 1, m + 1] = w1[m] * ax


def _camera():
    return Camera(position=(0.0, 1.7, 0.0), look_at=(0.0, 2.0, -10.0), up=(0.0, 1.0, 0.0), fov_y=60.0, width=64,
                  height=36, near=0.1, far=60.0)


def _rect():
    # light heading into the view, nearly along it: the slices' rays differ a lot in their step
    return NonlinearRectification.from_camera(_camera(), (0.1, -0.25, -1.0), rows=ROWS, cols=COLS)


def _lookups(segments, coords, sigma_t=0.3, reference="least", segment_depth=0.0):
    rect = _rect()
    tau = reference_ray(rect, reference).optical_steps(sigma_t)
    weights = ray_weights(segments, tau, rect, sigma_t, segment_depth=segment_depth)
    n = len(coords)
    cols = wp.zeros((n, MAX_SEGMENTS + 2), dtype=wp.int32)
    w = wp.zeros((n, 2, MAX_SEGMENTS + 2), dtype=wp.float32)
    rows = wp.zeros((n, 2), dtype=wp.int32)
    wp.launch(lookup_kernel, n, [weights, wp.array(coords, dtype=wp.vec3), 0, cols, w, rows])
    return rect, tau, cols.numpy(), w.numpy(), rows.numpy()


def _coords(n, seed=0):
    """Rectified end points of n camera rays through random pixels, at random distances."""
    rng = np.random.default_rng(seed)
    cam = _camera()
    corners = cam.frustum_corners()[4:]  # far plane: 0 bottom-left, 1 bottom-right, 2 top-left, 3 top-right
    a, b = rng.uniform(0, 1, (2, n, 1))
    far = (1 - b) * ((1 - a) * corners[0] + a * corners[1]) + b * ((1 - a) * corners[2] + a * corners[3])
    d = far - np.asarray(cam.position)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points = np.asarray(cam.position) + d * rng.uniform(0.5, 50.0, (n, 1))
    return _rect().world_to_rectified(points).astype(np.float32)


@pytest.mark.parametrize("segments", [1, 2, 3, 5, MAX_SEGMENTS])
def test_weights_are_convex_and_sum_to_one(segments):
    _, _, cols, w, _ = _lookups(segments, _coords(400))
    assert np.allclose(w.sum(axis=(1, 2)), 1.0, atol=2e-5)
    assert w.min() >= -1e-5  # least reference: every ray decays at least as fast -> convex mix (float32 rounding)
    # the interior cuts come in increasing order, before the end's columns
    for c in cols:
        used = c[c >= 0]
        assert np.all(np.diff(used[:-1]) > 0) and (len(used) <= segments + 1)


def test_one_segment_is_the_bilinear_fetch():
    coords = _coords(50, seed=1)
    _, _, cols, w, rows = _lookups(1, coords)
    x = np.clip(coords[:, 0] * COLS - 1.0, 0, COLS - 1)
    i0 = np.floor(x).astype(int)
    assert np.array_equal(cols[:, 0], i0)
    assert np.allclose(w[:, :, 0] + w[:, :, 1], np.stack([1 - (w[:, 1, :2].sum(1)), w[:, 1, :2].sum(1)], 1))
    assert np.allclose(w[:, :, 1].sum(1), x - i0, atol=1e-5)


def _ray_means(rect, tau, cols, w, rows, coords, signal, sigma_t):
    """(segment estimate, exact own-weight mean, reference-weight mean) of a 0/1 signal per row."""
    i = np.arange(COLS)
    est, exact, ref = [], [], []
    for n, (u, _, z) in enumerate(coords):
        j = rows[n, 0]
        wr = np.exp(-tau[j] * i)
        prefix = np.cumsum(wr * signal[j]) / np.cumsum(wr)  # the stored normalised prefix means
        used = cols[n] >= 0
        est.append(sum(w[n, r, used] @ prefix[cols[n, used]] for r in (0, 1)))
        x = np.clip(u * COLS - 1.0, 0, COLS - 1)
        theta = rect.theta_hi - z * rect.theta_len
        own = np.exp(-sigma_t * rect.delta_perp / np.sin(theta) * i) * (i <= x)
        exact.append(own @ signal[j] / own.sum())
        i0 = int(np.floor(x))
        ref.append(np.interp(x, [i0, min(i0 + 1, COLS - 1)], prefix[[i0, min(i0 + 1, COLS - 1)]]))
    return np.array(est), np.array(exact), np.array(ref)


def test_segments_approach_each_rays_own_transmittance():
    rng = np.random.default_rng(3)
    # a dark run near the camera, then lit with shadowed runs (the window room: the dark room, then the sky outside)
    i = np.arange(COLS)
    signal = ((i[None, :] >= rng.integers(2, 12, (ROWS, 1)))
              & ((i[None, :] // rng.integers(5, 15, (ROWS, 1))) % 3 != 0)).astype(float)
    coords = _coords(300, seed=4)
    coords[:, 1] = (np.floor(coords[:, 1] * ROWS) + 0.5) / ROWS  # row centres: one row per look-up
    errors = {}
    for k in (1, 3, 6):
        rect, tau, cols, w, rows = _lookups(k, coords)
        est, exact, ref = _ray_means(rect, tau, cols, w, rows, coords, signal, 0.3)
        errors[k] = np.abs(est - exact).mean()
    ref_error = np.abs(ref - exact).mean()
    # measured: reference weights (the least step) 0.051, 3 segments 0.022, 6 segments 0.011
    assert errors[1] == pytest.approx(ref_error, rel=1e-4)
    assert errors[3] < 0.5 * errors[1]
    assert errors[6] < 0.65 * errors[3]


def test_adaptive_segments_match_the_fixed_count_with_fewer_cuts():
    """segment_depth > 0: a ray takes one segment per that much optical-depth mismatch with its row reference, at
    most ``segments``. On the test_segments signal the adaptive 8 at 0.15 is about as close to each ray's own mean as
    8 fixed segments (measured 0.0092 against 0.0085; 3 fixed 0.022) with fewer segments per ray (measured mean 4.4
    against 6.4; cuts closer than a column merge), and a ray decaying like its reference reads one segment."""
    rng = np.random.default_rng(3)
    i = np.arange(COLS)
    signal = ((i[None, :] >= rng.integers(2, 12, (ROWS, 1)))
              & ((i[None, :] // rng.integers(5, 15, (ROWS, 1))) % 3 != 0)).astype(float)
    coords = _coords(300, seed=4)
    coords[:, 1] = (np.floor(coords[:, 1] * ROWS) + 0.5) / ROWS
    errors, taps = {}, {}
    for name, k, depth in (("fixed 3", 3, 0.0), ("fixed 8", MAX_SEGMENTS, 0.0), ("adaptive", MAX_SEGMENTS, 0.15)):
        rect, tau, cols, w, rows = _lookups(k, coords, segment_depth=depth)
        est, exact, _ = _ray_means(rect, tau, cols, w, rows, coords, signal, 0.3)
        errors[name] = np.abs(est - exact).mean()
        taps[name] = (cols >= 0).sum(axis=1).mean() - 1.0  # cut columns + the end's two, less one: segments
        assert np.allclose(w.sum(axis=(1, 2)), 1.0, atol=2e-5) and w.min() >= -1e-5
    assert errors["adaptive"] < 1.15 * errors["fixed 8"] and errors["adaptive"] < 0.5 * errors["fixed 3"]
    assert taps["adaptive"] < 0.8 * taps["fixed 8"]
    # no extinction: every ray decays like its reference, one segment each, the bilinear fetch
    _, _, cols, w, _ = _lookups(MAX_SEGMENTS, coords, sigma_t=0.0, segment_depth=0.15)
    _, _, cols1, w1, _ = _lookups(1, coords, sigma_t=0.0)
    np.testing.assert_array_equal(cols, cols1)
    np.testing.assert_allclose(w, w1, atol=1e-6)


def test_settings_segments_and_reference():
    p = PrefilteredSettings()
    assert p.segments_for(nonlinear=True, method="fourier") == 7 and p.segment_depth_for("fourier") == 0.08
    assert p.segments_for(True, method="fourier", light_behind=True) == 7
    assert p.segments_for(nonlinear=True, method="moments6") == 3 and p.segment_depth_for("moments6") == 0.0
    assert PrefilteredSettings(segment_depth=0.0).segment_depth_for("fourier") == 0.0
    # with the light behind the camera the moment methods take adaptive segments (grey media)
    assert p.segments_for(True, method="moments4", light_behind=True) == 6
    assert p.segment_depth_for("moments4", light_behind=True) == 0.15
    assert p.segments_for(True, coloured=True, method="moments6", light_behind=True) == 5
    assert p.segment_depth_for("moments6", light_behind=True, coloured=True) == 0.0
    assert PrefilteredSettings(segments=3).segments_for(True, method="moments6", light_behind=True) == 3
    assert PrefilteredSettings(segment_depth=0.0).segment_depth_for("moments6", light_behind=True) == 0.0
    assert p.segments_for(nonlinear=True) == 3 and p.reference_for(3) == "least"
    assert p.segments_for(nonlinear=False) == 1 and p.reference_for(1) == "pixels"
    assert PrefilteredSettings(weighting="average").segments_for(True) == 1
    assert PrefilteredSettings(splits=4).segments_for(True) == 1
    assert PrefilteredSettings(segments=5, reference_ray="optimal").reference_for(5) == "optimal"
    with pytest.raises(ValueError, match="segments"):
        PrefilteredSettings(segments=3, splits=2)
    with pytest.raises(ValueError, match="segments"):
        ray_weights(MAX_SEGMENTS + 1, None)
    with pytest.raises(ValueError, match="segment_depth"):
        ray_weights(3, None, segment_depth=-1.0)


def test_least_reference_is_the_slowest_decay_of_the_slice():
    rect = _rect()
    least = reference_ray(rect, "least")
    assert np.all(least.k_ref >= reference_ray(rect, "optimal").k_ref - 1e-12)
    assert np.all(least.k_ref >= reference_ray(rect, "bisectrix").k_ref - 1e-12)
