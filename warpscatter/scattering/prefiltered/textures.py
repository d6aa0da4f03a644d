"""The visibility representations of the prefiltered maps and their textures, as the kernels write and read them:
the Fourier basis (Klehm 2014 Eq. 8-9; 0-based index k, pair m = k // 2, c = pi (2 m + 1)) in float32 or the paper's
RGBA8 codes (App. A), and the moment maps in the storage modes of Peters 2017 (Sec. 2.4, 5.4.3). :mod:`.prefix_sums`
writes and :mod:`.filtered_lookups` reads them through the store / value functions here, so a storage format has one
home; a code decodes to exactly the float32 of the storage emulation (:func:`unorm_roundtrip`,
:func:`requantize_moments`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...runtime.device import default_device, module_options
from ...runtime.parallel import launch_rows
from ...shadows import moment_storage as ms
from ...shadows import moments as mm
from ..settings import MAX_COEFFICIENTS, MAX_DEPTH_WARP

module_options()


# ---- Fourier basis (Klehm 2014 Eq. 8-9) ------------------------------------------------------------------


@wp.func
def fourier_frequency(k: int) -> float:
    """c of the 0-based coefficient k: pair m = k // 2 uses c_(m+1) = pi (2 (m + 1) - 1) (Klehm 2014 Eq. 8)."""
    return wp.pi * float(2 * (k // 2) + 1)


@wp.func
def fourier_coefficient(k: int, z_r: float) -> float:
    """Ray coefficient a_k(z_r) of Klehm 2014 Eq. 8 (0-based k): 2/c cos(c z_r) for even k, -2/c sin(c z_r) odd."""
    c = fourier_frequency(k)
    if k % 2 == 0:
        return 2.0 / c * wp.cos(c * z_r)
    return -2.0 / c * wp.sin(c * z_r)


@wp.func
def fourier_basis(k: int, z_i: float) -> float:
    """Basis value B_k(z_i) of Klehm 2014 Eq. 8 (0-based k): sin(c z_i) for even k, cos(c z_i) odd; in [-1, 1]."""
    c = fourier_frequency(k)
    if k % 2 == 0:
        return wp.sin(c * z_i)
    return wp.cos(c * z_i)


@wp.func
def fourier_step(num_coefficients: int, z_r: float, z_i: float) -> float:
    """Truncated Fourier visibility of one texel, 0.5 + sum_k a_k(z_r) B_k(z_i) (Klehm 2014 Eq. 9), unclamped."""
    acc = float(0.5)
    for k in range(num_coefficients):
        acc += fourier_coefficient(k, z_r) * fourier_basis(k, z_i)
    return acc


@wp.func
def signed_unorm_code(x: float, levels: float) -> int:
    """Code of x in [-1, 1] stored as a [0, 1] unorm with ``levels`` = 2^bits - 1 steps (Klehm 2014 App. A: the sine
    and cosine values mapped to [0, 1]): round(clamp(0.5 x + 0.5, 0, 1) levels), in [0, levels]."""
    return int(wp.round(wp.clamp(0.5 * x + 0.5, 0.0, 1.0) * levels))


@wp.func
def signed_unorm_value(code: int, levels: float) -> float:
    """Value in [-1, 1] of a code of :func:`signed_unorm_code`: 2 (code / levels) - 1, in float32."""
    return 2.0 * (float(code) / levels) - 1.0


@wp.func
def unorm_roundtrip(x: float, levels: float) -> float:
    """x in [-1, 1] after storage as a unorm with ``levels`` = 2^bits - 1 steps (Klehm 2014 App. A), bit for bit what
    a look-up decodes; ``levels <= 0``: x unchanged (float storage)."""
    if levels <= 0.0:
        return x
    return signed_unorm_value(signed_unorm_code(x, levels), levels)


# ---- texture storage: what the prefilters write and the look-ups read -----------------------------------

#: Bits of the packed Fourier storage: the paper's RGBA8 filtered-basis textures (Klehm 2014 App. A).
FOURIER_UNORM_BITS = 8
#: Steps of the 8-bit Fourier codes (2^8 - 1).
FOURIER_UNORM_LEVELS = wp.constant(255.0)


@wp.struct
class FourierTables:
    """Constant tables of the Fourier look-ups, built once per device (:func:`fourier_tables`); each entry is the
    float32 value of the expression it replaces."""

    code_values: wp.array(dtype=wp.float32)  # (256,) signed_unorm_value of every RGBA8 code: the decode table
    pair_scales: wp.array(dtype=wp.float32)  # (MAX_COEFFICIENTS / 2,) 2 / c of pair m, c = pi (2 m + 1) (Eq. 8)


@wp.func
def warped_depth(z: float, c: float) -> float:
    """The exponential depth warp (Klehm 2014 Sec. 5: "a depth warp ... which basically stretches the rays"):
    (e^(c z) - 1) / (e^c - 1), monotone and mapping [0, 1] onto itself; c < 0 stretches the small depths (the end
    of the map towards the light, where rays near the epipole and their blockers crowd), c > 0 the large ones; c = 0
    is the identity (the callers skip it). The stored depths and the look-ups' ray depth are warped alike, so hard
    visibility is unchanged and only the representations' resolution moves."""
    return (wp.exp(c * z) - 1.0) / (wp.exp(c) - 1.0)


def check_depth_warp(c) -> float:
    """``c`` as a float, or ValueError unless finite with |c| <= MAX_DEPTH_WARP."""
    c = float(c)
    if not (math.isfinite(c) and abs(c) <= MAX_DEPTH_WARP):
        raise ValueError(f"depth_warp must be finite with |c| <= {MAX_DEPTH_WARP:g}, got {c}")
    return c


@wp.struct
class FilteredBasisArrays:
    """A Fourier basis texture as the kernels see it (:meth:`FilteredBasis.arrays`), in one of two storages (the
    other's array None), with its split regions (Klehm 2014 Sec. 3.3)."""

    basis: wp.array3d(dtype=wp.float32)  # (rows, cols, M) float32 values in [-1, 1] (bits 0)
    codes: wp.array3d(dtype=wp.uint8)  # (rows, cols, M) RGBA8 codes, signed_unorm_code (bits 8)
    tables: FourierTables  # the decode table of the codes and the look-ups' coefficient factors
    code_bits: int  # which array holds the texture: 0 (float32 values) or 8 (RGBA8 codes, Klehm 2014 App. A)
    weight_sums: wp.array2d(dtype=wp.float32)  # (rows, cols) region-local running weight sums (splits > 1)
    region_weights: wp.array2d(dtype=wp.float32)  # (rows, splits) reference-ray transmittance at region starts
    splits: int  # regions per row (1 = the plain filter)
    depth_warp: float  # the depth warp c of the stored depths (warped_depth; 0: none): look-ups warp z_r alike


@wp.func
def store_basis(tex: FilteredBasisArrays, j: int, i: int, k: int, x: float):
    """Write the value x of basis k at texel (j, i) in the texture's storage (8 bits: its code)."""
    if tex.code_bits == 0:
        tex.basis[j, i, k] = x
    else:
        tex.codes[j, i, k] = wp.uint8(signed_unorm_code(x, FOURIER_UNORM_LEVELS))


@wp.func
def basis_value(basis: wp.array3d(dtype=wp.float32), code_values: wp.array(dtype=wp.float32), j: int, i: int,
                k: int) -> float:
    """Value of basis k at texel (j, i) of a float32 texture (``code_values`` unused)."""
    return basis[j, i, k]


@wp.func
def basis_value(basis: wp.array3d(dtype=wp.uint8), code_values: wp.array(dtype=wp.float32), j: int, i: int,  # noqa: F811
                k: int) -> float:
    """Value of basis k at texel (j, i) of an RGBA8 texture: the decode table's entry for its code (the value of
    :func:`unorm_roundtrip`, bit for bit)."""
    return code_values[int(basis[j, i, k])]


@wp.func
def basis_texel(tex: FilteredBasisArrays, j: int, i: int, k: int) -> float:
    """Value of basis k at texel (j, i) in either storage (a branch per value; look-ups use :func:`basis_value`)."""
    if tex.code_bits == 0:
        return tex.basis[j, i, k]
    return basis_value(tex.codes, tex.tables.code_values, j, i, k)


@wp.func
def basis_shape(tex: FilteredBasisArrays):
    """(rows, cols, M) of a Fourier basis texture."""
    if tex.code_bits == 0:
        return tex.basis.shape[0], tex.basis.shape[1], tex.basis.shape[2]
    return tex.codes.shape[0], tex.codes.shape[1], tex.codes.shape[2]


#: ``FilteredMomentArrays.code_bits``: which array holds a moment map's texels (0: float32 values).
CODE_BITS_UNORM16 = wp.constant(16)  # uint16 codes, one per channel (STORAGE4_UNORM16, STORAGE6_UNORM16)
CODE_BITS_UNORM10 = wp.constant(10)  # six 10-bit codes packed in one uint64 per texel (STORAGE6_UNORM10)

#: Texture layout of each moment storage mode: (moments, STORAGE*_ value) -> (numpy dtype, words per texel), at the
#: bits per texel of Peters 2017: 64 / 128 (four moments), 64 (60 used) / 96 / 192 (six).
MOMENT_TEXEL_LAYOUT = {(4, int(mm.STORAGE4_UNORM16)): (np.uint16, 4), (4, int(mm.STORAGE4_FLOAT32)): (np.float32, 4),
                       (6, int(mm.STORAGE6_UNORM10)): (np.uint64, 1), (6, int(mm.STORAGE6_UNORM16)): (np.uint16, 6),
                       (6, int(mm.STORAGE6_FLOAT32)): (np.float32, 6)}


@wp.func
def moment_code_bits(num_moments: int, storage: int) -> int:
    """Bits per fixed-point channel of a moment storage mode (16 or 10), 0 for the float32 modes."""
    if num_moments == 4 and storage == mm.STORAGE4_UNORM16:
        return mm.UNORM_BITS_STORAGE4_UNORM16
    if num_moments == 6 and storage == mm.STORAGE6_UNORM16:
        return mm.UNORM_BITS_STORAGE6_UNORM16
    if num_moments == 6 and storage == mm.STORAGE6_UNORM10:
        return mm.UNORM_BITS_STORAGE6_UNORM10
    return 0


@wp.struct
class FilteredMomentArrays:
    """A prefiltered moment map as the kernels see it (:meth:`FilteredMoments.arrays`): the codes of its storage mode
    (Peters 2017 Sec. 2.4, 5.4.3; :data:`MOMENT_TEXEL_LAYOUT`) or float32 values in the array of ``code_bits``."""

    values: wp.array3d(dtype=wp.float32)  # (rows, cols, n) float32 values (code_bits 0)
    codes16: wp.array3d(dtype=wp.uint16)  # (rows, cols, n) 16-bit unorm codes of Theta*(b) (code_bits 16)
    codes10: wp.array2d(dtype=wp.uint64)  # (rows, cols) six 10-bit codes of Theta_6*(b) per word (code_bits 10)
    code_bits: int  # which array holds the texels: 0 (float32), CODE_BITS_UNORM16 or CODE_BITS_UNORM10
    num_moments: int  # 4 or 6
    storage: int  # moments.STORAGE4_* / STORAGE6_*: what the values mean (Theta*, moment bias)
    depth_warp: float  # the depth warp c of the stored depths (warped_depth; 0: none): look-ups warp z_r alike


@wp.func
def requantize_moments(t: mm.vec6, num_moments: int, storage: int) -> mm.vec6:
    """A filtered texel rounded to the mode's fixed point again, as float32 (float modes: unchanged): the emulation of
    :func:`store_moment_texel` then :func:`moment_texel`, bit for bit (the quantization transforms are affine)."""
    bits = moment_code_bits(num_moments, storage)
    if bits == 0:
        return t
    return mm.vec6(mm.unorm_round(t[0], bits), mm.unorm_round(t[1], bits), mm.unorm_round(t[2], bits),
                   mm.unorm_round(t[3], bits), mm.unorm_round(t[4], bits), mm.unorm_round(t[5], bits))


@wp.func
def store_moment_texel(tex: FilteredMomentArrays, j: int, i: int, t: mm.vec6):
    """Write the stored moments t (slots 0..n-1) to texel (j, i) in the map's storage mode."""
    if tex.code_bits == 0:
        q = requantize_moments(t, tex.num_moments, tex.storage)
        for k in range(wp.static(6)):  # unrolled (see moment_texel_values)
            if k < tex.num_moments:
                tex.values[j, i, k] = q[k]
    elif tex.code_bits == CODE_BITS_UNORM10:
        tex.codes10[j, i] = ms.pack_unorm10x6(t)
    else:
        for k in range(wp.static(6)):
            if k < tex.num_moments:
                tex.codes16[j, i, k] = wp.uint16(ms.unorm_encode(t[k], CODE_BITS_UNORM16))


@wp.func
def moment_texel_values(values: wp.array3d(dtype=wp.float32), j: int, i: int, num: int) -> mm.vec6:
    """Stored moments (slots 0..num-1) of texel (j, i) of a float32 moment map."""
    t = mm.vec6()
    for k in range(wp.static(6)):  # unrolled: t stays in registers (a dynamic index spills it)
        if k < num:
            t[k] = values[j, i, k]
    return t


@wp.func
def moment_texel_values(codes: wp.array3d(dtype=wp.uint16), j: int, i: int, num: int) -> mm.vec6:  # noqa: F811
    """Stored moments of texel (j, i) of a 16-bit moment map: the values of its unorm codes."""
    t = mm.vec6()
    for k in range(wp.static(6)):  # unrolled, as above
        if k < num:
            t[k] = ms.unorm_decode(int(codes[j, i, k]), CODE_BITS_UNORM16)
    return t


@wp.func
def moment_texel_values(codes: wp.array2d(dtype=wp.uint64), j: int, i: int, num: int) -> mm.vec6:  # noqa: F811
    """Stored moments of texel (j, i) of a STORAGE6_UNORM10 map: the six channels of its 64-bit word (one load)."""
    word = codes[j, i]
    return mm.vec6(ms.unpack_unorm10(word, 0), ms.unpack_unorm10(word, 1), ms.unpack_unorm10(word, 2),
                   ms.unpack_unorm10(word, 3), ms.unpack_unorm10(word, 4), ms.unpack_unorm10(word, 5))


@wp.func
def moment_texel(tex: FilteredMomentArrays, j: int, i: int) -> mm.vec6:
    """Stored moments of texel (j, i) of any moment map (a branch per texel; the look-ups dispatch once)."""
    if tex.code_bits == 0:
        return moment_texel_values(tex.values, j, i, tex.num_moments)
    if tex.code_bits == CODE_BITS_UNORM10:
        return moment_texel_values(tex.codes10, j, i, tex.num_moments)
    return moment_texel_values(tex.codes16, j, i, tex.num_moments)


@wp.kernel
def fourier_tables_kernel(tables: FourierTables):
    # the decode table of an RGBA8 texture (the value of every code) and the factors 2 / c of the pairs
    c = wp.tid()
    tables.code_values[c] = signed_unorm_value(c, FOURIER_UNORM_LEVELS)
    if c < tables.pair_scales.shape[0]:
        tables.pair_scales[c] = 2.0 / fourier_frequency(2 * c)


@wp.kernel
def decode_basis_kernel(tex: FilteredBasisArrays, out: wp.array3d(dtype=wp.float32), offset: int):
    # the float32 values of a Fourier basis texture (tests, inspection)
    j, i = wp.tid()
    j += offset
    for k in range(out.shape[2]):
        out[j, i, k] = basis_texel(tex, j, i, k)


@wp.kernel
def decode_moments_kernel(tex: FilteredMomentArrays, out: wp.array3d(dtype=wp.float32), offset: int):
    # the float32 stored moments of a moment map (tests, inspection)
    j, i = wp.tid()
    j += offset
    t = moment_texel(tex, j, i)
    for k in range(out.shape[2]):
        out[j, i, k] = t[k]


def as_device_array(a, dtype, ndim: int, name: str, device) -> wp.array:
    if isinstance(a, wp.array):
        arr = a if a.device == wp.get_device(device) else a.to(device)
        if arr.dtype != dtype:
            raise ValueError(f"{name} must hold {dtype.__name__}, got {arr.dtype.__name__}")
    else:
        arr = wp.array(np.ascontiguousarray(a, dtype=wp.dtype_to_numpy(dtype)), dtype=dtype,
                       device=device)
    if arr.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}D array, got shape {arr.shape}")
    return arr


_TABLES: dict = {}


def fourier_tables(device=None) -> FourierTables:
    """The :class:`FourierTables` of a device, built on first use."""
    device = default_device(device)
    key = str(wp.get_device(device))
    if key not in _TABLES:
        tables = FourierTables()
        tables.code_values = wp.empty(2**FOURIER_UNORM_BITS, dtype=wp.float32, device=device)
        tables.pair_scales = wp.empty(MAX_COEFFICIENTS // 2, dtype=wp.float32, device=device)
        wp.launch(fourier_tables_kernel, tables.code_values.shape, [tables], device=device)
        _TABLES[key] = tables
    return _TABLES[key]


def basis_texture(rows: int, cols: int, num: int, bits: int, device) -> wp.array:
    """An uninitialised (rows, cols, M) Fourier basis texture: float32 (bits 0) or uint8 codes (bits 8)."""
    return wp.empty((rows, cols, num), dtype=wp.uint8 if bits else wp.float32, device=device)


@dataclass
class FilteredBasis:
    """A Fourier basis texture (:func:`~.prefix_sums.prefilter_weighted`'s output).

    Attributes:
        basis: (rows, cols, M) normalised filtered basis per split region: float32 values in [-1, 1], or uint8 RGBA8
            codes (Klehm 2014 App. A; value 2 code / 255 - 1).
        weight_sums: (rows, cols) float32 region-local running weight sums ((1, 1) placeholder when splits = 1).
        region_weights: (rows, splits) float32 reference-ray transmittance at every region start (region 0: 1).
        splits: regions per row (Klehm 2014 Sec. 3.3); depth_warp: the depth warp c of the stored depths.
    """

    basis: wp.array
    weight_sums: wp.array
    region_weights: wp.array
    splits: int
    depth_warp: float = 0.0

    @property
    def bits(self) -> int:
        """Bits per stored value: 0 (float32) or 8 (RGBA8 codes)."""
        return FOURIER_UNORM_BITS if self.basis.dtype == wp.uint8 else 0

    def arrays(self) -> FilteredBasisArrays:
        """The texture as the kernels read it (:class:`FilteredBasisArrays`)."""
        a = FilteredBasisArrays()
        a.code_bits, a.tables = self.bits, fourier_tables(self.basis.device)
        if a.code_bits:
            a.codes = self.basis
        else:
            a.basis = self.basis
        a.weight_sums, a.region_weights, a.splits = self.weight_sums, self.region_weights, int(self.splits)
        a.depth_warp = float(self.depth_warp)
        return a

    @property
    def nbytes(self) -> int:
        """Bytes allocated for what an evaluation reads (with split regions also the weight sums)."""
        return int(self.basis.capacity + (self.weight_sums.capacity + self.region_weights.capacity
                                          if self.splits > 1 else 0))

    def values(self) -> wp.array:
        """(rows, cols, M) float32 Warp array: the values the look-ups see (RGBA8 codes decoded)."""
        out = wp.empty(self.basis.shape, dtype=wp.float32, device=self.basis.device)
        launch_rows(decode_basis_kernel, self.basis.shape[:2], [self.arrays(), out], device=self.basis.device)
        return out


def basis_arrays(basis, name: str, device) -> FilteredBasisArrays:
    """:class:`FilteredBasisArrays` of a (rows, cols, M) float32 or uint8 (RGBA8 codes) numpy or Warp array."""
    is_codes = (basis.dtype == wp.uint8) if isinstance(basis, wp.array) else np.asarray(basis).dtype == np.uint8
    arr = as_device_array(basis, wp.uint8 if is_codes else wp.float32, 3, name, device)
    return FilteredBasis(basis=arr, weight_sums=None, region_weights=None, splits=1).arrays()


#: Storage modes of prefiltered moment maps: bits per texel -> moments.STORAGE*_ constant, per moment count.
MOMENT_STORAGE = {4: {64: int(mm.STORAGE4_UNORM16), 128: int(mm.STORAGE4_FLOAT32)},
                  6: {64: int(mm.STORAGE6_UNORM10), 96: int(mm.STORAGE6_UNORM16), 192: int(mm.STORAGE6_FLOAT32)}}

_WARP_DTYPES = {np.float32: wp.float32, np.uint16: wp.uint16, np.uint64: wp.uint64}


@dataclass
class FilteredMoments:
    """A prefiltered moment map (:func:`~.prefix_sums.prefilter_moments`'s output).

    Attributes:
        texels: in the layout of the storage mode (:data:`MOMENT_TEXEL_LAYOUT`): float32 (rows, cols, n) canonical
            moments (128 / 192 bits per texel), uint16 (rows, cols, n) 16-bit codes of Theta*(b) (64 / 96 bits) or
            uint64 (rows, cols) six 10-bit codes (64 bits); or float32 decoded values of a fixed-point mode.
        num_moments: 4 or 6; storage: the moments.STORAGE4_* / STORAGE6_* mode.
    """

    texels: wp.array
    num_moments: int
    storage: int
    depth_warp: float = 0.0

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the map."""
        return int(self.texels.shape[0]), int(self.texels.shape[1])

    @property
    def bits_per_texel(self) -> int:
        """Bits per texel of the storage mode (64, 96, 128 or 192)."""
        return 8 * int(self.texels.capacity) // (self.shape[0] * self.shape[1])

    @property
    def nbytes(self) -> int:
        """Bytes allocated for the texture an evaluation reads."""
        return int(self.texels.capacity)

    def arrays(self) -> FilteredMomentArrays:
        """The texture as the kernels read it (:class:`FilteredMomentArrays`)."""
        a = FilteredMomentArrays()
        a.num_moments, a.storage = int(self.num_moments), int(self.storage)
        a.depth_warp = float(self.depth_warp)
        packed = MOMENT_TEXEL_LAYOUT[(a.num_moments, a.storage)][0]
        if self.texels.dtype == wp.float32:
            a.values, a.code_bits = self.texels, 0
        elif self.texels.dtype == _WARP_DTYPES[packed] == wp.uint16:
            a.codes16, a.code_bits = self.texels, int(CODE_BITS_UNORM16)
        elif self.texels.dtype == _WARP_DTYPES[packed] == wp.uint64:
            a.codes10, a.code_bits = self.texels, int(CODE_BITS_UNORM10)
        else:
            raise ValueError(f"{self.texels.dtype.__name__} texels do not hold storage mode {self.storage} of "
                             f"{self.num_moments} moments")
        return a

    def values(self) -> wp.array:
        """(rows, cols, n) float32 Warp array: the stored moments the look-ups see (codes decoded; Theta* still
        applied in the fixed-point modes)."""
        out = wp.empty((*self.shape, self.num_moments), dtype=wp.float32, device=self.texels.device)
        launch_rows(decode_moments_kernel, self.shape, [self.arrays(), out], device=self.texels.device)
        return out



def moment_texture(rows: int, cols: int, num_moments: int, storage: int, device) -> FilteredMoments:
    """An uninitialised (rows, cols) moment map in the layout of its storage mode (:data:`MOMENT_TEXEL_LAYOUT`)."""
    dtype, words = MOMENT_TEXEL_LAYOUT[(num_moments, storage)]
    shape = (rows, cols) if words == 1 else (rows, cols, words)
    return FilteredMoments(texels=wp.empty(shape, dtype=_WARP_DTYPES[dtype], device=device), num_moments=num_moments,
                           storage=storage)

__all__ = [
    "CODE_BITS_UNORM10",
    "CODE_BITS_UNORM16",
    "FOURIER_UNORM_BITS",
    "FOURIER_UNORM_LEVELS",
    "MOMENT_STORAGE",
    "MOMENT_TEXEL_LAYOUT",
    "FilteredBasis",
    "FilteredBasisArrays",
    "FilteredMomentArrays",
    "FilteredMoments",
    "FourierTables",
    "as_device_array",
    "basis_arrays",
    "basis_shape",
    "basis_texel",
    "basis_texture",
    "basis_value",
    "decode_basis_kernel",
    "decode_moments_kernel",
    "fourier_basis",
    "fourier_coefficient",
    "fourier_frequency",
    "fourier_step",
    "fourier_tables",
    "fourier_tables_kernel",
    "moment_code_bits",
    "moment_texel",
    "moment_texel_values",
    "moment_texture",
    "requantize_moments",
    "signed_unorm_code",
    "signed_unorm_value",
    "store_basis",
    "store_moment_texel",
    "unorm_roundtrip",
]
