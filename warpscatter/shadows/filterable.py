"""Filterable shadow-map formats: what a texel holds and how a filtered texel becomes a shadow intensity.

Every format stores a vector b(z) of the signed depth z in [-1, 1] of :mod:`.msm`, so that filtering the map filters
the depth distribution (Peters et al. 2017, Sec. 2.1): ``msm`` (Peters 2017, 64/128 bits), ``msm2015`` (Peters and
Klein 2015), ``vsm`` (Donnelly and Lauritzen 2006) and ``evsm`` (Lauritzen and McCool 2008), with Cantelli's
inequality for the last two; float16 channels are emulated by rounding after every write. The table of formats is
in docs/design/shadows-scene.md.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..runtime.device import module_options
from . import moments as mm

module_options()

#: Format ints (``MomentShadowParams.storage``).
FORMAT_MSM_UNORM16 = mm.STORAGE4_UNORM16
FORMAT_MSM_FLOAT32 = mm.STORAGE4_FLOAT32
FORMAT_MSM2015_UNORM16 = wp.constant(2)
FORMAT_MSM2015_FLOAT32 = wp.constant(3)
FORMAT_VSM_FLOAT16 = wp.constant(4)
FORMAT_VSM_FLOAT32 = wp.constant(5)
FORMAT_EVSM_FLOAT16 = wp.constant(6)
FORMAT_EVSM_FLOAT32 = wp.constant(7)

#: (method, bits per texel) -> format.
FORMATS = {("msm", 64): int(FORMAT_MSM_UNORM16), ("msm", 128): int(FORMAT_MSM_FLOAT32),
           ("msm2015", 64): int(FORMAT_MSM2015_UNORM16), ("msm2015", 128): int(FORMAT_MSM2015_FLOAT32),
           ("vsm", 32): int(FORMAT_VSM_FLOAT16), ("vsm", 64): int(FORMAT_VSM_FLOAT32),
           ("evsm", 64): int(FORMAT_EVSM_FLOAT16), ("evsm", 128): int(FORMAT_EVSM_FLOAT32)}
#: The bits per texel each method offers (the first is its default).
BITS_OF_METHOD = {"msm": (64, 128), "msm2015": (64, 128), "vsm": (32, 64), "evsm": (64, 128)}

#: EVSM exponents (c+, c-) of Peters 2017 Fig. 4: 64 bits (a) and 128 bits (e).
EVSM_EXPONENTS = {64: (5.54, 5.54), 128: (40.0, 5.54)}
#: Largest exponent whose squared warp fits the channel (float16 max 65504, float32 3.4e38).
EVSM_MAX_EXPONENT = {64: float(np.log(65504.0) / 2.0), 128: float(np.log(3.4e38) / 2.0)}

#: Peters and Klein 2015's quantization transform: row vector b times this, + offset on the first channel.
QUANTIZATION_2015 = np.array([
    [-2.07224649, 13.7948857237, 0.105877704, 9.7924062118],
    [32.23703778, -59.4683975703, -1.9077466311, -33.7652110555],
    [-68.571074599, 82.0359750338, 9.3496555107, 47.9456096605],
    [39.3703274134, -35.364903257, -6.6543490743, -23.9728048165],
])
QUANTIZATION_OFFSET_2015 = 0.035955884801
_Q2015 = wp.constant(wp.mat44(*QUANTIZATION_2015.T.reshape(-1)))
_Q2015_INV = wp.constant(wp.mat44(*np.linalg.inv(QUANTIZATION_2015.T).reshape(-1)))
_Q2015_OFFSET = wp.constant(wp.vec4(QUANTIZATION_OFFSET_2015, 0.0, 0.0, 0.0))

#: alpha_b of msm2015 (64 bits: Peters and Klein 2015; 128 bits: Peters 2017 Fig. 4d), b* of (delta_0 + delta_1) / 2.
MOMENT_BIAS_2015_UNORM16 = wp.constant(3.0e-5)
MOMENT_BIAS_2015_FLOAT32 = wp.constant(2.0e-6)
BIAS_VECTOR_2015 = wp.constant(wp.vec4(0.5, 0.5, 0.5, 0.5))

#: Variance floor of the Cantelli bound in (signed depth)^2 units per channel precision, against acne.
VSM_MIN_VARIANCE_FLOAT16 = wp.constant(1.0e-4)
VSM_MIN_VARIANCE_FLOAT32 = wp.constant(1.0e-6)


@wp.func
def uses_float16(fmt: int) -> bool:
    """True for the formats with float16 channels (vsm 32 bits, evsm 64 bits)."""
    return fmt == FORMAT_VSM_FLOAT16 or fmt == FORMAT_EVSM_FLOAT16


@wp.func
def float16_round4(t: wp.vec4) -> wp.vec4:
    """Each channel rounded to the nearest float16 (a write to a 16-bit float render target)."""
    return wp.vec4(float(wp.float16(t[0])), float(wp.float16(t[1])), float(wp.float16(t[2])),
                   float(wp.float16(t[3])))


@wp.func
def texel_from_depth(z: float, fmt: int, exponents: wp.vec2) -> wp.vec4:
    """b(z) of a depth sample at signed depth z (before encoding): the vector filtering averages."""
    if fmt == FORMAT_VSM_FLOAT16 or fmt == FORMAT_VSM_FLOAT32:
        return wp.vec4(z, z * z, 0.0, 0.0)
    if fmt == FORMAT_EVSM_FLOAT16 or fmt == FORMAT_EVSM_FLOAT32:
        pos = wp.exp(exponents[0] * z)  # Sec. 2.2: two exponentially warped depths
        neg = wp.exp(-exponents[1] * z)
        return wp.vec4(pos, pos * pos, -neg, neg * neg)
    if fmt == FORMAT_MSM2015_UNORM16 or fmt == FORMAT_MSM2015_FLOAT32:
        return mm.moments4_from_depth(0.5 * z + 0.5)  # msm2015: depth in [0, 1]
    return mm.moments4_from_depth(z)


@wp.func
def encode_texel(b: wp.vec4, fmt: int) -> wp.vec4:
    """b(z) -> the texel domain before rounding: a quantization transform for the 16-bit moment formats."""
    if fmt == FORMAT_MSM2015_UNORM16:
        return _Q2015 @ b + _Q2015_OFFSET
    if fmt == FORMAT_MSM_UNORM16:
        return mm.quantization_transform4(b)
    return b


@wp.func
def round_texel(t: wp.vec4, fmt: int) -> wp.vec4:
    """Write a texel-domain value to the format's channels: 16-bit unorm, float16 or float32 (unchanged)."""
    if fmt == FORMAT_MSM_UNORM16 or fmt == FORMAT_MSM2015_UNORM16:
        return mm.unorm_round4(t, mm.UNORM_BITS_STORAGE4_UNORM16)
    if uses_float16(fmt):
        return float16_round4(t)
    return t


@wp.func
def store_texel(b: wp.vec4, fmt: int) -> wp.vec4:
    """Texel contents after writing b(z) (or an average of them) in format ``fmt``: encode, then round."""
    if fmt == FORMAT_MSM_UNORM16 or fmt == FORMAT_MSM_FLOAT32:
        return mm.store_moments4(b, fmt)
    return round_texel(encode_texel(b, fmt), fmt)


@wp.func
def load_texel(t: wp.vec4, fmt: int) -> wp.vec4:
    """A (filtered) texel -> the average of b(z) it holds (the quantization transforms reverted)."""
    if fmt == FORMAT_MSM_UNORM16 or fmt == FORMAT_MSM_FLOAT32:
        return mm.load_moments4(t, fmt)
    if fmt == FORMAT_MSM2015_UNORM16:
        return _Q2015_INV @ (t - _Q2015_OFFSET)
    return t


@wp.func
def cantelli_shadow(mean: float, second: float, z_f: float, min_variance: float) -> float:
    """Lower bound of Z(z < z_f) by Cantelli's inequality (Sec. 2.2), sigma^2 clamped below at ``min_variance``."""
    if not (z_f > mean):
        return 0.0
    variance = wp.max(second - mean * mean, min_variance)
    d = z_f - mean
    return 1.0 - variance / (variance + d * d)


@wp.func
def shadow_intensity(t: wp.vec4, z_f: float, fmt: int, exponents: wp.vec2, overdarkening: float) -> float:
    """Filtered texel -> over-darkened shadow intensity in [0, 1] at signed fragment depth z_f (depth-biased)."""
    if fmt == FORMAT_MSM_UNORM16 or fmt == FORMAT_MSM_FLOAT32:
        shadow = mm.msm4_shadow_intensity(mm.load_biased_moments4(t, fmt), z_f)
    elif fmt == FORMAT_MSM2015_UNORM16 or fmt == FORMAT_MSM2015_FLOAT32:
        alpha = MOMENT_BIAS_2015_FLOAT32
        if fmt == FORMAT_MSM2015_UNORM16:
            alpha = MOMENT_BIAS_2015_UNORM16
        b = mm.bias_moments4(load_texel(t, fmt), alpha, BIAS_VECTOR_2015)
        shadow = mm.msm4_shadow_intensity(b, 0.5 * z_f + 0.5)
    elif fmt == FORMAT_VSM_FLOAT16 or fmt == FORMAT_VSM_FLOAT32:
        floor = VSM_MIN_VARIANCE_FLOAT32
        if fmt == FORMAT_VSM_FLOAT16:
            floor = VSM_MIN_VARIANCE_FLOAT16
        shadow = cantelli_shadow(t[0], t[1], z_f, floor)
    else:  # EVSM: the Cantelli bound of each warp; the lit fraction is the smaller upper bound
        floor = VSM_MIN_VARIANCE_FLOAT32
        if fmt == FORMAT_EVSM_FLOAT16:
            floor = VSM_MIN_VARIANCE_FLOAT16
        pos = wp.exp(exponents[0] * z_f)
        neg = -wp.exp(-exponents[1] * z_f)
        s_pos = cantelli_shadow(t[0], t[1], pos, floor * (exponents[0] * pos) * (exponents[0] * pos))
        s_neg = cantelli_shadow(t[2], t[3], neg, floor * (exponents[1] * neg) * (exponents[1] * neg))
        shadow = wp.max(s_pos, s_neg)
    return mm.scale_shadow_intensity(shadow, overdarkening)


def format_of(method: str, bits: int) -> int:
    """The format int of a shadow method and its bits per texel.

    Raises:
        ValueError: a method without that storage (the message lists what it offers).
    """
    if (method, bits) not in FORMATS:
        offered = BITS_OF_METHOD.get(method)
        raise ValueError(f"storage: {method} stores {' or '.join(map(str, offered))} bits per texel, not {bits}"
                         if offered else f"method: {method!r} is not a filterable shadow map")
    return FORMATS[(method, bits)]


def evsm_exponents(bits: int, exponents=None) -> tuple[float, float]:
    """(c+, c-) of an EVSM: the given pair or Fig. 4's for the storage.

    Raises:
        ValueError: an exponent <= 0, or one whose squared warp overflows the channel (float16: c <= 5.545).
    """
    c = tuple(float(x) for x in (exponents if exponents is not None else EVSM_EXPONENTS[bits]))
    limit = EVSM_MAX_EXPONENT[bits]
    if len(c) != 2 or not all(0.0 < x <= limit for x in c):
        raise ValueError(f"evsm_exponents: both must lie in (0, {limit:.3f}] for {bits}-bit storage "
                         f"(exp(2c) must fit the channel), got {list(c)}")
    return c


__all__ = ["BITS_OF_METHOD", "EVSM_EXPONENTS", "EVSM_MAX_EXPONENT", "FORMATS", "QUANTIZATION_2015",
           "QUANTIZATION_OFFSET_2015", "cantelli_shadow", "encode_texel", "evsm_exponents", "format_of",
           "load_texel", "round_texel", "shadow_intensity", "store_texel", "texel_from_depth"]
