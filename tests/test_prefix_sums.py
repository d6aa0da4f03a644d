"""Tests of the Fourier and moment prefix sums and their look-ups (warpscatter.scattering.prefiltered.prefix_sums,
filtered_lookups; Klehm 2014 Sec. 3, Eq. 8-11, App. A)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from warpscatter.runtime.device import default_device, module_options
from warpscatter.scattering.prefiltered import filtered_lookups as fl
from warpscatter.scattering.prefiltered import prefix_sums as pf
from warpscatter.scattering.prefiltered import textures as ft
from warpscatter.scattering.rectify.bounds import NonlinearRectification
from warpscatter.scattering.rectify.reference_rays import reference_ray
from warpscatter.scene.camera import Camera
from warpscatter.shadows import moment_storage as ms
from warpscatter.shadows import moments as mm

module_options()

MARGIN = 0.5 * 0.1 / 1.1  # frustum rays have rectified depth in [MARGIN, 1 - MARGIN] (10 % guard band)


# ---- float64 references ----------------------------------------------------------------------------------


def _np_basis(z: np.ndarray, m: int) -> np.ndarray:
    """B_k(z) of Klehm 2014 Eq. 8, 0-based k, shape z.shape + (m,)."""
    c = np.pi * (2 * (np.arange(m) // 2) + 1)
    ang = c * np.asarray(z, np.float64)[..., None]
    return np.where(np.arange(m) % 2 == 0, np.sin(ang), np.cos(ang))


def _np_coefficients(z: np.ndarray, m: int) -> np.ndarray:
    c = np.pi * (2 * (np.arange(m) // 2) + 1)
    ang = c * np.asarray(z, np.float64)[..., None]
    return np.where(np.arange(m) % 2 == 0, 2.0 / c * np.cos(ang), -2.0 / c * np.sin(ang))


def _np_prefix(depth: np.ndarray, m: int, tau: np.ndarray) -> np.ndarray:
    """cumsum(w B) / cumsum(w) per row, w_i = exp(-(i-1) tau) - exp(-i tau) (Eq. 11) or 1 when tau = 0."""
    b = _np_basis(depth, m)
    i = np.arange(1, depth.shape[1] + 1, dtype=np.float64)
    out = np.empty_like(b)
    for j, t in enumerate(np.asarray(tau, np.float64)):
        w = np.ones_like(i) if t == 0.0 else np.exp(-(i - 1) * t) - np.exp(-i * t)
        out[j] = np.cumsum(w[:, None] * b[j], axis=0) / np.cumsum(w)[:, None]
    return out


# ---- basis functions -----------------------------------------------------------------------------------------


def test_fourier_funcs_in_user_kernel():
    """A user kernel calls the public @wp.funcs; Eq. 9 converges to the step H away from the jump."""

    @wp.kernel
    def user_kernel(
        zr: wp.array(dtype=float),
        zi: wp.array(dtype=float),
        m: int,
        a: wp.array2d(dtype=float),
        b: wp.array2d(dtype=float),
        step: wp.array(dtype=float),
    ):
        n = wp.tid()
        for k in range(m):
            a[n, k] = ft.fourier_coefficient(k, zr[n])
            b[n, k] = ft.fourier_basis(k, zi[n])
        step[n] = ft.fourier_step(m, zr[n], zi[n])

    device = default_device()
    rng = np.random.default_rng(0)
    zr, zi = rng.uniform(0.0, 1.0, 2000), rng.uniform(0.0, 1.0, 2000)
    m = 128
    a = wp.empty((2000, m), dtype=float, device=device)
    b = wp.empty((2000, m), dtype=float, device=device)
    step = wp.empty(2000, dtype=float, device=device)
    wp.launch(
        user_kernel,
        2000,
        [wp.array(zr, dtype=float, device=device), wp.array(zi, dtype=float, device=device), m, a, b, step],
        device=device,
    )
    assert np.abs(a.numpy() - _np_coefficients(zr, m)).max() < 1e-5  # measured 2.9e-7
    assert np.abs(b.numpy() - _np_basis(zi, m)).max() < 2e-4  # measured 4.5e-5 (float32 arguments c z, c <= 128 pi)
    far = np.abs(zr - zi) > 0.05
    h = (zr <= zi).astype(float)  # V = 1 when the ray depth is not behind the blocker
    assert np.abs(step.numpy() - h)[far].max() < 0.04  # measured 0.018 for M = 128 (Gibbs tail 0.05 from the jump)


# ---- prefix sums ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("m, tol", [(4, 3e-6), (32, 3e-5), (128, 1.5e-4)])  # measured 6.9e-7, 6.6e-6, 3.6e-5
def test_prefix_sums_match_float64(m, tol):
    """Fused (Listing 3) and two-pass (Listings 1-2) filters equal cumsum(w B) / cumsum(w) in float64."""
    rng = np.random.default_rng(m)
    rows, cols = 12, 384
    depth = rng.uniform(0.0, 1.0, (rows, cols)).astype(np.float32)
    depth[3, 100:] = 1.0  # empty texels
    tau = np.array([0.0, 0.0, 1e-4, 3e-3, 0.01, 0.02, 0.05, 0.2, 1.0, 5.0, 30.0, 100.0], np.float32)
    ref = _np_prefix(depth, m, tau)
    fused = pf.prefilter_depth(depth, m, tau).numpy()
    assert fused.shape == (rows, cols, m) and fused.dtype == np.float32
    two_pass = pf.prefix_filter(pf.fourier_basis_textures(depth, m), tau, bases_per_thread=2).numpy()
    assert np.abs(fused - ref).max() < tol
    assert np.abs(two_pass - ref).max() < tol
    # basis grouping of the two-pass filter does not change the result
    grouped = pf.prefix_filter(pf.fourier_basis_textures(depth, m), tau, bases_per_thread=min(m, 6)).numpy()
    assert np.array_equal(grouped, two_pass)
    # no weights (optical_step None) is the plain average of Listing 1
    avg = pf.prefilter_depth(depth, m).numpy()
    assert np.abs(avg - _np_prefix(depth, m, np.zeros(rows))).max() < tol


def test_eight_bit_storage():
    """bits=8 stores every filtered value as an RGBA8 code (uint8, M bytes per texel) whose value 2 code / 255 - 1
    lies within half a step of the float value."""
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.0, 1.0, (6, 200)).astype(np.float32)
    tau = np.full(6, 0.01, np.float32)
    full = pf.prefilter_depth(depth, 32, tau).numpy()
    packed = pf.prefilter_weighted(depth, 32, tau, bits=8)
    assert packed.basis.dtype == wp.uint8 and packed.basis.shape == (6, 200, 32) and packed.bits == 8
    assert packed.nbytes == 6 * 200 * 32 and full.nbytes == 4 * packed.nbytes  # one byte per coefficient
    codes = packed.basis.numpy()
    assert codes.min() < 40 and codes.max() > 215  # the codes use the range (the basis values span [-1, 1])
    q8 = packed.values().numpy()
    assert q8.dtype == np.float32
    np.testing.assert_array_equal(q8, 2.0 * (codes.astype(np.float32) / np.float32(255.0)) - 1.0)
    assert np.abs(q8 - full).max() <= 1.0 / 255.0 + 1e-6  # half a step of 2/255
    b8 = pf.fourier_basis_textures(depth, 32, bits=8)
    assert b8.dtype == wp.uint8
    b32 = pf.fourier_basis_textures(depth, 32).numpy()
    assert np.abs((b8.numpy() / 255.0 * 2.0 - 1.0) - b32).max() <= 1.0 / 255.0 + 1e-6
    # visibility from 8-bit textures stays close to float storage (Klehm 2014 Sec. 3.3); both read the same way
    q = np.stack([rng.uniform(0.0, 1.0, 3000), rng.uniform(0.0, 1.0, 3000), rng.uniform(MARGIN, 1 - MARGIN, 3000)], 1)
    vis8 = fl.evaluate_visibility(packed, q)
    diff = np.abs(vis8 - fl.evaluate_visibility(full, q))
    assert diff.max() < 0.015  # measured 0.0046
    assert np.array_equal(vis8, fl.evaluate_visibility(packed.basis, q))  # a bare uint8 array is RGBA8
    assert np.array_equal(vis8, fl.evaluate_visibility(q8, q))  # the decoded float32 texture: same visibility


# ---- packed storage: the codes decode to the storage emulation, bit for bit -------------------------------


@wp.func
def emulated_unorm_round(x: float, bits: int) -> float:
    """The fixed-point emulation as written before packed storage (moment_storage.unorm_round, literally)."""
    scale = wp.float32((1 << bits) - 1)
    xc = x
    if wp.isnan(xc):
        xc = 0.0
    xc = wp.clamp(xc, 0.0, 1.0)
    return wp.floor(xc * scale + 0.5) / scale


@wp.func
def emulated_unorm_roundtrip(x: float, levels: float) -> float:
    """The RGBA8 emulation as written before packed storage (filtered_textures.unorm_roundtrip, literally)."""
    q = wp.round(wp.clamp(0.5 * x + 0.5, 0.0, 1.0) * levels) / levels
    return 2.0 * q - 1.0


@wp.kernel
def emulate_rgba8_kernel(values: wp.array3d(dtype=float), out: wp.array3d(dtype=float)):
    j, i = wp.tid()
    for k in range(values.shape[2]):
        out[j, i, k] = emulated_unorm_roundtrip(values[j, i, k], 255.0)


@wp.kernel
def emulate_moment_filter_kernel(rd: pf.RectifiedTexels, optical_step: wp.array(dtype=float),
                                 column_length: wp.array(dtype=float), num: int, storage: int,
                                 out: wp.array3d(dtype=float)):
    # the moment prefilter as it was before packed storage: the same running filter, every texel written as float32
    # values rounded to the mode's fixed point
    j = wp.tid()
    tau = optical_step[j]
    uniform = column_length.shape[0] == 1
    w_first, step = pf.texel_weight(1.0, column_length[0], tau * column_length[0])
    state = mm.vec6()
    transmittance = float(1.0)
    sum_w = float(0.0)
    bits = int(0)
    if num == 4 and storage == mm.STORAGE4_UNORM16:
        bits = 16
    if num == 6 and storage == mm.STORAGE6_UNORM16:
        bits = 16
    if num == 6 and storage == mm.STORAGE6_UNORM10:
        bits = 10
    for i in range(rd.depth.shape[1]):
        w, transmittance = pf.next_texel_weight(transmittance, uniform, w_first, step, column_length, i, tau)
        sum_w += w
        if sum_w > 0.0:
            z1, z2, w2 = pf.texel_depths(rd, j, i)
            state = state + (w / sum_w) * (pf.stored_moments(z1, z2, w2, num, storage) - state)
        for k in range(num):
            q = state[k]
            if bits > 0:
                q = emulated_unorm_round(q, bits)
            out[j, i, k] = q


def _emulate_rgba8(values: wp.array) -> np.ndarray:
    out = wp.empty(values.shape, dtype=float, device=values.device)
    wp.launch(emulate_rgba8_kernel, values.shape[:2], [values, out], device=values.device)
    return out.numpy()


def _emulate_moments(depth, m: int, bits: int, tau, lengths=None) -> np.ndarray:
    dev = default_device()
    rd = pf.rectified_texels(depth, dev)
    rows, cols = rd.depth.shape
    lengths = np.ones(1, np.float32) if lengths is None else np.asarray(lengths, np.float32)
    out = wp.empty((rows, cols, m), dtype=float, device=dev)
    wp.launch(emulate_moment_filter_kernel, rows,
              [rd, wp.array(np.broadcast_to(np.float32(tau), rows).copy(), dtype=float, device=dev),
               wp.array(lengths, dtype=float, device=dev), m, ft.MOMENT_STORAGE[m][bits], out], device=dev)
    return out.numpy()


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype == np.float32 and np.array_equal(a.view(np.uint32),
                                                                                     b.view(np.uint32))


#: moments, bits per texel -> (dtype, words per texel) of the packed texture
PACKED = {(4, 64): (np.uint16, 4), (4, 128): (np.float32, 4), (6, 64): (np.uint64, 1), (6, 96): (np.uint16, 6),
          (6, 192): (np.float32, 6)}


@pytest.mark.parametrize("m, bits", sorted(PACKED))
def test_moment_textures_have_the_real_dtype_and_bytes(m, bits):
    """Every moment storage mode allocates exactly its bits per texel: uint16 codes (64 / 96 bits), one uint64 with
    six 10-bit codes (64 bits) or float32 (128 / 192 bits)."""
    depth = np.random.default_rng(1).uniform(0.0, 1.0, (5, 30)).astype(np.float32)
    fm = pf.prefilter_moments(depth, m, 0.05, storage_bits=bits)
    dtype, words = PACKED[(m, bits)]
    assert fm.texels.dtype == wp.dtype_from_numpy(dtype) and fm.texels.numpy().dtype == dtype
    assert fm.texels.shape == ((5, 30) if words == 1 else (5, 30, words))
    assert fm.nbytes == fm.texels.numpy().nbytes == 5 * 30 * bits // 8 and fm.bits_per_texel == bits
    assert fm.values().shape == (5, 30, m)


@pytest.mark.parametrize("m, bits", [(4, 64), (6, 96), (6, 64), (4, 128), (6, 192)])
def test_packed_moments_decode_to_the_emulation_bit_for_bit(m, bits):
    """The codes of every mode decode to exactly the float32 texels of the previous emulation (the same filter with
    every value rounded to the fixed point and kept in float32): plain and two-depth texels, uneven columns."""
    from warpscatter.scattering.rectify.taps import SparseRectifiedDepth

    rng = np.random.default_rng(m * bits)
    rows, cols = 7, 90
    depth = rng.uniform(0.0, 1.0, (rows, cols)).astype(np.float32)
    depth[2, 40:] = 1.0
    lengths = rng.uniform(0.3, 3.0, cols)
    z2, w2 = rng.uniform(0.0, 1.0, (2, rows, cols)).astype(np.float32)
    w2[:, ::3] = 0.0
    dev = default_device()
    sparse = SparseRectifiedDepth(*(wp.array(a, dtype=float, device=dev) for a in (depth, z2, w2)))
    for rd, tau, cl in ((depth, 0.03, None), (depth, 0.0, lengths), (sparse, 0.2, None)):
        fm = pf.prefilter_moments(rd, m, tau, cl, storage_bits=bits)
        want = _emulate_moments(rd, m, bits, tau, cl)
        assert _same_bits(fm.values().numpy(), want)
    if bits in (128, 192):
        return
    # the codes are real: a texel is what the bytes say (channel k of a 64-bit word in bits 10 k .. 10 k + 9)
    codes = fm.texels.numpy()
    if bits == 64 and m == 6:
        assert np.all(codes >> np.uint64(60) == 0)  # 60 of the 64 bits used
        fields = (codes[..., None] >> (np.uint64(10) * np.arange(6, dtype=np.uint64))) & np.uint64(1023)
        decoded = fields.astype(np.float32) / np.float32(1023.0)
    else:
        decoded = codes.astype(np.float32) / np.float32(65535.0)
        assert codes.max() > 60000 and codes.min() < 5000  # Theta* uses the range
    assert _same_bits(decoded, want)


def test_packed_fourier_decodes_to_the_emulation_bit_for_bit():
    """RGBA8 codes (fused filter with splits and uneven columns, the two-pass filter, the basis textures) decode to
    exactly the previous emulation: the float32 values rounded to the 8-bit grid."""
    rng = np.random.default_rng(11)
    rows, cols, m = 9, 120, 12
    depth = rng.uniform(0.0, 1.0, (rows, cols)).astype(np.float32)
    tau = rng.uniform(0.0, 0.05, rows).astype(np.float32)
    lengths = rng.uniform(0.5, 2.0, cols)
    for splits in (1, 3):
        full = pf.prefilter_weighted(depth, m, tau, lengths, splits=splits)
        packed = pf.prefilter_weighted(depth, m, tau, lengths, splits=splits, bits=8)
        assert _same_bits(packed.values().numpy(), _emulate_rgba8(full.basis))
        assert np.array_equal(packed.weight_sums.numpy(), full.weight_sums.numpy())  # the weights stay float32
        assert packed.nbytes == full.nbytes - 3 * rows * cols * m  # 1 instead of 4 bytes per value
    basis = pf.fourier_basis_textures(depth, m)
    basis8 = pf.fourier_basis_textures(depth, m, bits=8)
    emulated_basis = _emulate_rgba8(basis)
    assert _same_bits(ft.FilteredBasis(basis8, None, None, 1).values().numpy(), emulated_basis)
    # the two-pass filter reads RGBA8 basis textures as their values and writes RGBA8 codes
    two_pass = pf.prefix_filter(basis8, tau, bits=8)
    from_emulated = pf.prefix_filter(emulated_basis, tau)
    assert two_pass.dtype == wp.uint8
    assert _same_bits(ft.FilteredBasis(two_pass, None, None, 1).values().numpy(), _emulate_rgba8(from_emulated))


def test_texel_codes_round_trip():
    """unorm_round is decode(encode) bit for bit (the MSM emulation is unchanged), codes lie in [0, 2^n - 1], a
    packed 10-bit texel holds the six codes; the Fourier codes and tables give unorm_roundtrip and 2 / c exactly.
    (The code helpers of moment_storage are underscored until the moments facade re-exports them.)"""

    @wp.kernel
    def codes_kernel(x: wp.array(dtype=float), bits: int, rounded: wp.array(dtype=float),
                     emulated: wp.array(dtype=float), decoded: wp.array(dtype=float), codes: wp.array(dtype=int)):
        n = wp.tid()
        rounded[n] = ms.unorm_round(x[n], bits)
        emulated[n] = emulated_unorm_round(x[n], bits)
        codes[n] = ms.unorm_encode(x[n], bits)
        decoded[n] = ms.unorm_decode(codes[n], bits)

    @wp.kernel
    def pack_kernel(q: wp.array(dtype=mm.vec6), words: wp.array(dtype=wp.uint64), values: wp.array(dtype=mm.vec6)):
        n = wp.tid()
        words[n] = ms.pack_unorm10x6(q[n])
        for k in range(6):
            values[n][k] = ms.unpack_unorm10(words[n], k)

    @wp.kernel
    def fourier_kernel(x: wp.array(dtype=float), tables: ft.FourierTables, roundtrip: wp.array(dtype=float),
                       emulated: wp.array(dtype=float), table_value: wp.array(dtype=float),
                       scales: wp.array2d(dtype=float)):
        n = wp.tid()
        roundtrip[n] = ft.unorm_roundtrip(x[n], 255.0)
        emulated[n] = emulated_unorm_roundtrip(x[n], 255.0)
        table_value[n] = tables.code_values[ft.signed_unorm_code(x[n], 255.0)]
        if n < tables.pair_scales.shape[0]:
            scales[n, 0] = tables.pair_scales[n]
            scales[n, 1] = 2.0 / ft.fourier_frequency(2 * n)

    dev = default_device()
    rng = np.random.default_rng(2)
    x = np.concatenate([rng.uniform(-0.2, 1.2, 20000), (np.arange(2048) + 0.5) / 1023.0,
                        (np.arange(512) + 0.5) / 65535.0,  # halfway between codes
                        [0.0, 1.0, -0.0, np.nan, np.inf, -np.inf, 0.5 / 1023.0]]).astype(np.float32)
    xa = wp.array(x, dtype=float, device=dev)
    n = len(x)
    for bits in (8, 10, 16, 24):
        outs = [wp.empty(n, dtype=float, device=dev) for _ in range(3)] + [wp.empty(n, dtype=int, device=dev)]
        wp.launch(codes_kernel, n, [xa, bits, *outs], device=dev)
        rounded, emulated, decoded, codes = (a.numpy() for a in outs)
        assert _same_bits(rounded, emulated) and _same_bits(decoded, emulated)
        assert codes.min() == 0 and codes.max() == (2**bits - 1 if bits < 24 else 2**24)  # 24: float32 scale 2^24
        assert np.all(codes[np.isnan(x)] == 0)
    # every code of the texture formats decodes to code / (2^n - 1) in float32 (a GPU's unorm fetch)
    for bits in (8, 10, 16):
        c = np.arange(2**bits)
        dec = wp.empty(len(c), dtype=float, device=dev)
        out = [wp.empty(len(c), dtype=float, device=dev) for _ in range(2)] + [dec, wp.empty(len(c), dtype=int,
                                                                                             device=dev)]
        wp.launch(codes_kernel, len(c), [wp.array(c.astype(np.float32) / np.float32(2**bits - 1), dtype=float,
                                                  device=dev), bits, *out], device=dev)
        assert np.array_equal(out[3].numpy(), c)  # the value of a code encodes back to it
        assert _same_bits(dec.numpy(), c.astype(np.float32) / np.float32(2**bits - 1))
    q = rng.uniform(-0.1, 1.1, (500, 6)).astype(np.float32)
    words = wp.empty(500, dtype=wp.uint64, device=dev)
    values = wp.zeros(500, dtype=mm.vec6, device=dev)
    wp.launch(pack_kernel, 500, [wp.array(q, dtype=mm.vec6, device=dev), words, values], device=dev)
    fields = (words.numpy()[:, None] >> (np.uint64(10) * np.arange(6, dtype=np.uint64))) & np.uint64(1023)
    outs = [wp.empty(q.size, dtype=float, device=dev) for _ in range(3)] + [wp.empty(q.size, dtype=int, device=dev)]
    wp.launch(codes_kernel, q.size, [wp.array(q.ravel(), dtype=float, device=dev), 10, *outs], device=dev)
    assert np.array_equal(fields, outs[3].numpy().reshape(500, 6))  # channel k: the code of q_k in bits 10 k ..
    assert np.all(words.numpy() >> np.uint64(60) == 0)
    assert _same_bits(values.numpy(), fields.astype(np.float32) / np.float32(1023.0))
    # Fourier: codes and the decode table give unorm_roundtrip; the pair factors are 2 / c
    tables = ft.fourier_tables(dev)
    outs = [wp.empty(n, dtype=float, device=dev) for _ in range(3)]
    scales = wp.empty((tables.pair_scales.shape[0], 2), dtype=float, device=dev)
    xf = np.concatenate([rng.uniform(-1.1, 1.1, n - 259), 2.0 * (np.arange(256) + 0.5) / 255.0 - 1.0,
                         [-1.0, 0.0, 1.0]]).astype(np.float32)  # the midpoints between codes too
    wp.launch(fourier_kernel, n, [wp.array(xf, dtype=float, device=dev), tables, *outs, scales], device=dev)
    roundtrip, emulated, table_value = (a.numpy() for a in outs)
    assert _same_bits(roundtrip, emulated) and _same_bits(table_value, emulated)
    assert len(np.unique(table_value)) == 256  # every code met
    assert _same_bits(scales.numpy()[:, 0].copy(), scales.numpy()[:, 1].copy())


# ---- evaluation ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("m, worst, mean", [(4, 0.35, 0.06), (32, 0.06, 0.01), (128, 0.02, 0.003)])
def test_no_occluder_average_visibility_is_one(m, worst, mean):
    """All blockers at the far end: average visibility 1 up to the truncated series' ringing."""
    rng = np.random.default_rng(4)
    fb = pf.prefilter_depth(np.ones((8, 256), np.float32), m)
    q = np.stack([rng.uniform(0.0, 1.0, 4000), rng.uniform(0.0, 1.0, 4000), rng.uniform(MARGIN, 1 - MARGIN, 4000)], 1)
    f = fl.evaluate_visibility(fb, q)
    assert f.max() <= 1.0
    # measured 1 - min: 0.32 (M=4), 0.049 (32), 0.017 (128); mean 0.047, 0.0061, 0.0016
    assert 1.0 - f.min() < worst and np.mean(1.0 - f) < mean


@pytest.mark.parametrize("m, tol", [(32, 0.06), (128, 0.015)])  # measured 0.048 and 0.0082 (worst relative error)
def test_no_occluder_transmittance_integral(m, tol):
    """Per-pixel path from world end points: F * integral_0^s exp(-sigma_t t) dt equals the analytic integral."""
    cam = Camera(position=[1, 2, 10], look_at=[0, 1, 0], up=[0, 1, 0], fov_y=55, width=24, height=16, near=0.1, far=40)
    sigma_t = 0.15
    for light in ([-0.3, -0.8, -0.5], cam.forward, -cam.forward):
        rect = NonlinearRectification.from_camera(cam, light, rows=64, cols=128)
        tau = reference_ray(rect).optical_steps(sigma_t)
        fb = pf.prefilter_depth(np.ones((rect.rows, rect.cols), np.float32), m, tau)
        dirs = cam.ray_directions().reshape(-1, 3)
        s = np.random.default_rng(5).uniform(0.05, 1.0, len(dirs)) * cam.far_distance(dirs)
        frac, integral = fl.evaluate_points(fb, rect, cam.position + s[:, None] * dirs, sigma_t)
        exact = (1.0 - np.exp(-sigma_t * s)) / sigma_t
        assert np.abs(integral / exact - 1.0).max() < tol
        np.testing.assert_allclose(integral, frac * exact, rtol=1e-5)
        # sigma_t = 0: the integral is F * s (the average-visibility form of Eq. 2)
        _, lin = fl.evaluate_points(fb, rect, cam.position + s[:, None] * dirs, 0.0)
        np.testing.assert_allclose(lin, frac * s, rtol=1e-5)


def _step_map(rows, cols, z_block):
    """A planar occluder in the rectified map: columns >= start[j] of row j hold blocker depth z_block."""
    start = np.linspace(0.1, 0.9, rows) * cols
    start = start.astype(int)
    depth = np.ones((rows, cols), np.float32)
    for j in range(rows):
        depth[j, start[j] :] = z_block
    return depth, start


def _exact_step_fraction(u, z_r, start, z_block, cols, tau):
    """Weighted lit fraction of a ray ending at column position u * cols (continuous, weights exp(-tau x))."""
    p = u * cols
    if tau == 0.0:
        total, lit_block = p, np.minimum(p, start)
    else:
        total = -np.expm1(-tau * p) / tau
        lit_block = -np.expm1(-tau * np.minimum(p, start)) / tau
    return np.where(z_r <= z_block, 1.0, lit_block / total)


@pytest.mark.parametrize("tau", [0.0, 0.02])
def test_step_occluder_ringing_decreases_with_m(tau):
    rows, cols, z_block = 8, 256, 0.5
    depth, start = _step_map(rows, cols, z_block)
    rng = np.random.default_rng(6)
    n = 4000
    row = rng.integers(0, rows, n)
    q = np.stack([rng.uniform(0.01, 1.0, n), (row + 0.5) / rows, rng.uniform(MARGIN, 1 - MARGIN, n)], 1)
    exact = _exact_step_fraction(q[:, 0], q[:, 2], start[row], z_block, cols, tau)
    errors = []
    for m in (4, 32, 128):
        f = fl.evaluate_visibility(pf.prefilter_depth(depth, m, np.full(rows, tau, np.float32)), q)
        errors.append(np.mean(np.abs(f - exact)))
    # measured mean |error| (tau 0 / 0.02): M=4 0.053 / 0.048, M=32 0.0088 / 0.0075, M=128 0.0024 / 0.0020
    assert errors[0] > 2.0 * errors[1] > 4.0 * errors[2]
    assert errors[2] < 0.004


def test_row_wrap_for_full_circle():
    """With wrap_rows the rows at v = 0 and v = 1 are neighbours; without it the edge row is clamped."""
    depth = np.ones((8, 64), np.float32)
    depth[-1, :] = 0.0  # last row fully blocked for every ray
    fb = pf.prefilter_depth(depth, 32)
    q = np.array([[0.5, 0.0, 0.5], [0.5, 1.0, 0.5], [0.5, 0.5 / 8, 0.5]])
    wrapped = fl.evaluate_visibility(fb, q, wrap_rows=True)
    clamped = fl.evaluate_visibility(fb, q, wrap_rows=False)
    assert wrapped[0] == pytest.approx(0.5, abs=0.02)  # measured 0.5: halfway between row 0 and the last row
    assert wrapped[1] == pytest.approx(0.5, abs=0.02)
    assert clamped[0] == pytest.approx(1.0, abs=0.02) and clamped[1] == pytest.approx(0.0, abs=0.02)
    assert wrapped[2] == pytest.approx(1.0, abs=0.02)  # a row centre reads that row alone (measured 0.990, ringing)


# ---- end to end against exact visibility ------------------------------------------------------------------


def _analytic_rectified_map(rect, spheres):
    """Rectified blocker depth straight from the geometry: each texel's light ray is intersected with the spheres."""
    u = (np.arange(rect.cols) + 0.5) / rect.cols
    v = (np.arange(rect.rows) + 0.5) / rect.rows
    r = u[None, :] * rect.r_max
    phi = rect.phi_mid + (v[:, None] - 0.5) * rect.phi_span
    x, y = r * np.cos(phi), r * np.sin(phi)
    base = rect.position + np.stack([x, y, np.zeros_like(x)], -1) @ rect.to_light  # light-view z = 0
    light = rect.light_direction
    z_hit = np.full(base.shape[:2], np.inf)  # light-view z of the first caster on each texel's light ray
    for c, rad in spheres:
        oc = base - c
        b = oc @ light
        disc = b * b - (np.sum(oc * oc, -1) - rad * rad)
        z_hit = np.where(disc >= 0.0, np.minimum(z_hit, -b - np.sqrt(np.maximum(disc, 0.0))), z_hit)
    theta = np.arctan2(np.broadcast_to(r, z_hit.shape), z_hit)
    depth = np.where(np.isfinite(z_hit), np.clip((rect.theta_hi - theta) / rect.theta_len, 0.0, 1.0), 1.0)
    return depth.astype(np.float32)


def _exact_integral(cam, dirs, s, light, spheres, sigma_t, steps=2000):
    """integral_0^s exp(-sigma_t t) V(x_t) dt by midpoint quadrature with analytic sphere visibility."""
    total = np.zeros(len(dirs))
    for k in range(steps):
        t = (k + 0.5) / steps * s
        x = cam.position + t[:, None] * dirs
        lit = np.ones(len(dirs), bool)
        for c, rad in spheres:
            oc = x - c
            b = oc @ (-light)
            disc = b * b - (np.sum(oc * oc, 1) - rad * rad)
            lit &= ~((disc >= 0.0) & (-b + np.sqrt(np.maximum(disc, 0.0)) > 0.0))
        total += lit * np.exp(-sigma_t * t) * s / steps
    return total


def test_end_to_end_against_exact_visibility():
    """Prefiltered F * integral against quadrature with exact visibility along pixel rays ending on the far plane."""
    light = np.array([-0.3, -0.8, -0.5])
    light /= np.linalg.norm(light)
    cam = Camera(position=[0, 2, 12], look_at=[0, 1, 0], up=[0, 1, 0], fov_y=60, width=24, height=16, near=0.1, far=25)
    spheres = [(np.array([0.0, 2.0, 0.0]), 3.0), (np.array([3.0, 1.0, 4.0]), 1.5), (np.array([-2.0, 3.5, 7.0]), 1.2)]
    sigma_t = 0.08
    rect = NonlinearRectification.from_camera(cam, light, rows=256, cols=512)
    depth = _analytic_rectified_map(rect, spheres)
    dirs = cam.ray_directions().reshape(-1, 3)
    s = cam.far_distance(dirs)
    exact = _exact_integral(cam, dirs, s, light, spheres, sigma_t)
    unocc = (1.0 - np.exp(-sigma_t * s)) / sigma_t
    assert 0.05 < 1.0 - exact.sum() / unocc.sum()  # the rays see shadows (measured 0.078 of the light blocked)
    tau = reference_ray(rect).optical_steps(sigma_t)
    rel = {}
    for m in (4, 32, 128):
        _, integral = fl.evaluate_points(
            pf.prefilter_depth(depth, m, tau), rect, cam.position + s[:, None] * dirs, sigma_t
        )
        rel[m] = np.abs(integral - exact).sum() / exact.sum()
    # average visibility (Eq. 2) for comparison: transmittance weighting must be at least as good
    _, avg = fl.evaluate_points(pf.prefilter_depth(depth, 32), rect, cam.position + s[:, None] * dirs, sigma_t)
    rel_avg = np.abs(avg - exact).sum() / exact.sum()
    # measured relative L1: M=4 0.043, M=32 0.0106, M=128 0.0071; average visibility (M=32) 0.029
    assert rel[32] < 0.02 and rel[128] < 0.015
    assert rel[4] > rel[32] > rel[128]
    assert rel[32] < rel_avg


def test_bad_input_raises():
    depth = np.zeros((4, 8), np.float32)
    for m in (3, 2, 130, 6.5):
        with pytest.raises(ValueError, match="num_coefficients"):
            pf.prefilter_depth(depth, m)
    with pytest.raises(ValueError, match="bits"):
        pf.prefilter_depth(depth, 8, bits=20)
    with pytest.raises(ValueError, match="bases_per_thread"):
        pf.prefix_filter(np.zeros((4, 8, 8), np.float32), bases_per_thread=3)
    with pytest.raises(ValueError, match="optical_step"):
        pf.prefilter_depth(depth, 8, np.full(4, -1.0))
    with pytest.raises(ValueError, match="optical_step"):
        pf.prefilter_depth(depth, 8, np.zeros(5))
    with pytest.raises(ValueError, match="rectified_depth"):
        pf.prefilter_depth(np.zeros(8, np.float32), 8)
    with pytest.raises(ValueError, match="coords"):
        fl.evaluate_visibility(pf.prefilter_depth(depth, 8), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="sigma_t"):
        cam = Camera(
            position=[0, 2, 10], look_at=[0, 1, 0], up=[0, 1, 0], fov_y=50, width=16, height=9, near=0.1, far=20
        )
        rect = NonlinearRectification.from_camera(cam, [0, -1, 0], rows=4, cols=8)
        fl.evaluate_points(pf.prefilter_depth(depth, 8), rect, np.zeros((2, 3)), sigma_t=-1.0)
    assert math.isfinite(float(fl.evaluate_visibility(pf.prefilter_depth(depth, 8), np.zeros((1, 3)))[0]))


# ---- two depths per texel (filtering during resampling, Peters 2017 Sec. 5.2) -------------------------------


def _sparse(z1, z2, w2):
    from warpscatter.scattering.rectify.taps import SparseRectifiedDepth

    dev = wp.get_device()
    return SparseRectifiedDepth(*(wp.array(np.ascontiguousarray(a, np.float32), dtype=wp.float32, device=dev)
                                  for a in (z1, z2, w2)))


def _weighted_prefix_mean(basis: np.ndarray, tau: float) -> np.ndarray:
    """Normalised transmittance-weighted prefix means along axis 1 of (rows, cols, K) values (float64)."""
    cols = basis.shape[1]
    w = np.exp(-tau * np.arange(cols)) * (-np.expm1(-tau) / tau)
    return np.cumsum(w[None, :, None] * basis, axis=1) / np.cumsum(w)[None, :, None]


def test_two_depth_texels_filter_the_weighted_basis_mix():
    """A texel (z_1, z_2, w_2) filters (1 - w_2) B(z_1) + w_2 B(z_2) for the Fourier basis and for the moments;
    w_2 = 0 is bitwise the plain depth map."""
    rng = np.random.default_rng(4)
    rows, cols, tau = 6, 40, 0.07
    z1, z2 = rng.uniform(0.0, 1.0, (2, rows, cols))
    w2 = rng.uniform(0.0, 1.0, (rows, cols))
    w2[:, ::5] = 0.0
    k = np.arange(8)
    c = np.pi * (2 * (k // 2) + 1)

    def fourier(z):
        return np.where(k % 2 == 0, np.sin(c * z[..., None]), np.cos(c * z[..., None]))

    got = pf.prefilter_weighted(_sparse(z1, z2, w2), 8, tau).basis.numpy()
    mix = (1.0 - w2[..., None]) * fourier(z1) + w2[..., None] * fourier(z2)
    assert np.abs(got - _weighted_prefix_mean(mix, tau)).max() < 2e-5  # measured 8.3e-7
    for m in (4, 6):
        bits = 128 if m == 4 else 192  # float32 storage: the canonical moments
        got = pf.prefilter_moments(_sparse(z1, z2, w2), m, tau, storage_bits=bits).texels.numpy()
        p = np.arange(1, m + 1)
        s1, s2 = 2.0 * z1[..., None] - 1.0, 2.0 * z2[..., None] - 1.0
        mix = (1.0 - w2[..., None]) * s1**p + w2[..., None] * s2**p
        assert np.abs(got - _weighted_prefix_mean(mix, tau)).max() < 2e-5  # measured 1.0e-7 (4), 1.2e-7 (6)
    # the single-depth path is the w_2 = 0 case
    zero = np.zeros_like(w2)
    for a, b in ((pf.prefilter_weighted(_sparse(z1, z2, zero), 8, tau).basis, pf.prefilter_weighted(z1, 8, tau).basis),
                 (pf.prefilter_moments(_sparse(z1, z2, zero), 6, tau).texels, pf.prefilter_moments(z1, 6, tau).texels)):
        assert np.array_equal(a.numpy(), b.numpy())


def test_filtered_resampling_and_mipmapped_shadows_through_the_pipeline():
    """configs/canopy_moments.yaml turns on both: the stats report them and every image is finite."""
    from pathlib import Path

    from warpscatter.config import load_config
    from warpscatter.pipeline import render

    root = Path(__file__).resolve().parent.parent
    for method in ("moments6", "fourier"):
        cfg = load_config(root / "configs" / "canopy_moments.yaml",
                          ["camera.width=64", "camera.height=36", "render.scattering.shadow_map.resolution=128",
                           f"render.scattering.method={method}", "render.scattering.moments.storage_bits=null"])
        result = render(cfg, write=False)
        assert result.stats["resample_filter"] == "moments" and result.stats["resample_filter_px"] >= 1
        assert result.stats["msm_sampling"] == "mipmap" and result.stats["rectification"] == "nonlinear"
        for name, img in result.images.items():
            assert np.isfinite(img).all(), name
        assert result.images["scattering"].max() > 0.0


def test_depth_bounds_are_the_rows_prefix_min_and_max():
    """Issue #13: the per-row prefix bounds behind the wholly lit / shadowed look-ups, against numpy, for one depth
    and for the two-depth texels (both depths count when the second has weight)."""
    from warpscatter.scattering.rectify.taps import SparseRectifiedDepth

    rng = np.random.default_rng(3)
    z1 = rng.uniform(0.2, 0.9, (5, 40)).astype(np.float32)
    got = pf.depth_bounds(z1).numpy()
    np.testing.assert_array_equal(got[..., 0], np.minimum.accumulate(z1, axis=1))
    np.testing.assert_array_equal(got[..., 1], np.maximum.accumulate(z1, axis=1))
    z2 = rng.uniform(0.0, 1.0, z1.shape).astype(np.float32)
    w2 = np.where(rng.uniform(size=z1.shape) < 0.5, 0.0, rng.uniform(0.1, 1.0, z1.shape)).astype(np.float32)
    got = pf.depth_bounds(SparseRectifiedDepth(z1=z1, z2=z2, w2=w2)).numpy()
    lo = np.where(w2 > 0, np.minimum(z1, z2), z1)
    hi = np.where(w2 > 0, np.maximum(z1, z2), z1)
    np.testing.assert_array_equal(got[..., 0], np.minimum.accumulate(lo, axis=1))
    np.testing.assert_array_equal(got[..., 1], np.maximum.accumulate(hi, axis=1))
