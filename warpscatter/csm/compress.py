"""Lossless compression of depth-map sequences into segment lists (Ritschel 2007, Sec. 3.1, Eq. 1), and CSM files.

Per texel, over the maps i = 0 .. N-1, any stored depth z(i) with z_lo(i) <= z(i) < z_hi(i) is correct (dual depth
layers, Fig. 3). The compressor extends a piecewise-constant segment from i0 to the largest i_end with

    max {z_lo(i0), ..., z_lo(i_end)}  <  min {z_hi(i0), ..., z_hi(i_end)}                         (Eq. 1)

and stores (z_avg, i_end), z_avg the float32 midpoint kept inside the interval (Fig. 4); greedy extension gives the
fewest segments (:class:`SegmentLists`). z_hi = +inf bounds nothing; z_lo = z_hi (coincident surfaces) forms a
one-map segment. :class:`StreamingCompressor` needs O(M^2 x batch) memory.

:func:`save_csm` writes a CSM file; :func:`~.files.load_csm` reads and checks one.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..runtime import parallel
from ..runtime.device import default_device, module_options
from ..scene.meshes import geometry_digest  # noqa: F401  (the digest a CSM file records)
from .depthmaps import DEPTH_LAYERS, CubeMapSet, LatLongMapSet, latlong_frames
from .settings import CSMBuildSettings

module_options()

#: Version of the ``.npz`` layout written by :func:`save_csm`; :func:`~.files.load_csm` accepts only this one.
FORMAT_VERSION = 1
#: CSM kinds: orthographic lat-long maps (distant and semi-local lights), depth cube maps (fixed local lights).
KIND_LATLONG = "latlong"
KIND_CUBE = "cube"
KINDS = (KIND_LATLONG, KIND_CUBE)


@wp.func
def segment_open(lo: float, hi: float) -> bool:
    """Ritschel 2007 Eq. 1: the running interval [max z_lo, min z_hi) still admits a depth (or is unbounded)."""
    return lo < hi or hi == wp.inf


@wp.func
def segment_depth(lo: float, hi: float) -> float:
    """z_avg of a closed segment (Ritschel 2007 Fig. 4): the midpoint of max z_lo and min z_hi, kept in
    [lo, hi) in float32; lo when lo = hi (one-map segment of coincident surfaces); +inf when hi = +inf."""
    if hi == wp.inf:
        return wp.inf
    z = float(wp.float64(0.5) * (wp.float64(lo) + wp.float64(hi)))
    if not (z < hi):
        z = lo
    return z


@wp.struct
class StreamState:
    """Per-texel state of a streaming compression: the open segment's running max z_lo and min z_hi (``lo``,
    ``hi``), and the z_avg, i_end (M^2, max_batch + 1) and count of the segments the last batch closed."""

    lo: wp.array(dtype=wp.float32)
    hi: wp.array(dtype=wp.float32)
    out_depth: wp.array2d(dtype=wp.float32)
    out_end: wp.array2d(dtype=wp.int32)
    out_count: wp.array(dtype=wp.int32)


@wp.kernel
def compress_batch_kernel(
    z_lo: wp.array2d(dtype=wp.float32),
    z_hi: wp.array2d(dtype=wp.float32),
    first: int,
    last_map: int,
    state: StreamState,
    offset: int,
):
    """Texel t: push maps first .. first + rows - 1 through the open segment; the segments closed go to state.out_*."""
    t = wp.tid() + offset
    lo = state.lo[t]
    hi = state.hi[t]
    n = int(0)
    rows = z_lo.shape[0]
    for k in range(rows):
        a = z_lo[k, t]
        b = z_hi[k, t]
        i = first + k
        if i == 0:
            lo = a
            hi = b
        else:
            nlo = wp.max(lo, a)
            nhi = wp.min(hi, b)
            if segment_open(nlo, nhi):
                lo = nlo
                hi = nhi
            else:
                state.out_depth[t, n] = segment_depth(lo, hi)
                state.out_end[t, n] = i - 1
                n += 1
                lo = a
                hi = b
    if first + rows - 1 == last_map:
        state.out_depth[t, n] = segment_depth(lo, hi)
        state.out_end[t, n] = last_map
        n += 1
    state.lo[t] = lo
    state.hi[t] = hi
    state.out_count[t] = n


def _check_count(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


@dataclass
class CompressionStats:
    """What a compression of N maps of M^2 texels into S segments produced and cost: ``compressed_bytes`` = 8 S +
    4 (M^2 + 1), ``uncompressed_bytes`` = 4 N M^2 (float32 maps), ``peak_working_bytes`` = the most working memory
    held at once (output excluded; independent of N), seconds rendering (0 when maps were given) and compressing."""

    num_maps: int
    num_texels: int
    num_segments: int
    compressed_bytes: int
    uncompressed_bytes: int
    peak_working_bytes: int
    seconds_render: float = 0.0
    seconds_compress: float = 0.0

    @property
    def ratio(self) -> float:
        """uncompressed_bytes / compressed_bytes."""
        return self.uncompressed_bytes / max(1, self.compressed_bytes)

    @property
    def segments_per_texel(self) -> float:
        return self.num_segments / max(1, self.num_texels)


@dataclass
class SegmentLists:
    """Compressed depth functions of all texels (the output of Sec. 3.1).

    Attributes:
        seg_start: (M^2 + 1,) int32 lookup texture; texel t owns segments [seg_start[t], seg_start[t + 1]).
        seg_depth: (S,) float32 z_avg per segment.
        seg_end: (S,) int32 last sequence index i_end of each segment (inclusive; ascending per texel, the last N - 1).
        num_maps: N.
    """

    seg_start: np.ndarray
    seg_depth: np.ndarray
    seg_end: np.ndarray
    num_maps: int

    def decode(self, texel: int, sequence: int) -> float:
        """Host reference of the query's binary search (Sec. 3.2): z stored for ``texel`` in map ``sequence``."""
        s0, s1 = int(self.seg_start[texel]), int(self.seg_start[texel + 1])
        j = s0 + int(np.searchsorted(self.seg_end[s0:s1], sequence, side="left"))
        return float(self.seg_depth[j])

    def decode_all(self) -> np.ndarray:
        """Every stored depth, (N, M^2) float32 (small sets only: tests and inspection)."""
        counts = np.diff(self.seg_start.astype(np.int64))
        texel = np.repeat(np.arange(counts.size), counts)
        first_map = np.empty(self.seg_end.size, dtype=np.int64)  # first map index each segment covers
        first_map[1:] = self.seg_end[:-1].astype(np.int64) + 1
        first_map[self.seg_start[:-1][counts > 0]] = 0
        length = self.seg_end.astype(np.int64) + 1 - first_map
        seg = np.repeat(np.arange(self.seg_end.size), length)
        maps = np.arange(seg.size) - np.repeat(np.cumsum(length) - length, length) + first_map[seg]
        out = np.empty((self.num_maps, counts.size), dtype=np.float32)
        out[maps, texel[seg]] = self.seg_depth[seg]
        return out


class StreamingCompressor:
    """Compress ``num_maps`` = N depth maps of ``num_texels`` = M^2 texels, pushed in sequence order in batches of
    at most ``max_batch`` maps, into :class:`SegmentLists` (``threads``: CPU threads of the per-texel kernel)."""

    def __init__(self, num_texels: int, num_maps: int, max_batch: int, device: str | None = None,
                 threads: int | None = None):
        for name, v in (("num_texels", num_texels), ("num_maps", num_maps), ("max_batch", max_batch)):
            _check_count(name, v)
        if num_maps > 2**31 - 1:
            raise ValueError(f"num_maps must be < 2^31, got {num_maps}")
        self.device = default_device(device)
        self.threads = threads
        self.num_texels = int(num_texels)
        self.num_maps = int(num_maps)
        self.max_batch = int(max_batch)
        self.pushed = 0
        t = self.num_texels
        self._state = StreamState()
        self._state.lo = wp.zeros(t, dtype=wp.float32, device=self.device)
        self._state.hi = wp.zeros(t, dtype=wp.float32, device=self.device)
        self._state.out_depth = wp.empty((t, self.max_batch + 1), dtype=wp.float32, device=self.device)
        self._state.out_end = wp.empty((t, self.max_batch + 1), dtype=wp.int32, device=self.device)
        self._state.out_count = wp.zeros(t, dtype=wp.int32, device=self.device)
        self._counts = np.zeros(t, dtype=np.int64)  # segments per texel so far
        self._chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (texel, depth, end) per batch
        st = self._state
        held = (st.lo, st.hi, st.out_depth, st.out_end, st.out_count)
        self.working_bytes = sum(a.capacity for a in held) + self._counts.nbytes
        self.peak_working_bytes = self.working_bytes
        self.seconds = 0.0

    def _as_rows(self, z, name: str) -> wp.array:
        if isinstance(z, wp.array):
            if z.dtype != wp.float32 or z.ndim != 2 or z.shape[1] != self.num_texels:
                raise ValueError(f"{name} as a wp.array must be float32 with shape (B, {self.num_texels})")
            if str(z.device) != str(wp.get_device(self.device)) or not z.is_contiguous:
                z = wp.clone(z, device=self.device)
            return z
        a = np.asarray(z, dtype=np.float32)
        if a.ndim >= 2 and int(np.prod(a.shape[1:])) == self.num_texels:
            a = a.reshape(a.shape[0], self.num_texels)
        else:
            raise ValueError(f"{name} must have shape (B, {self.num_texels}) or (B, M, M), got {a.shape}")
        if np.isnan(a).any():
            raise ValueError(f"{name} contains NaN")
        return wp.array(np.ascontiguousarray(a), dtype=wp.float32, device=self.device)

    def push(self, z_lo, z_hi) -> None:
        """Compress the next batch of maps.

        Args:
            z_lo: (B, M^2) or (B, M, M) lower depths of the next B maps (numpy or Warp), +inf where empty.
            z_hi: same shape, upper depths, z_hi >= z_lo, +inf = unbounded.

        Raises:
            ValueError: wrong shapes, NaN, z_hi < z_lo, or a batch or total beyond the declared sizes.
        """
        t0 = time.perf_counter()
        lo = self._as_rows(z_lo, "z_lo")
        hi = self._as_rows(z_hi, "z_hi")
        if lo.shape != hi.shape:
            raise ValueError(f"z_lo and z_hi must have the same shape, got {lo.shape} and {hi.shape}")
        if not isinstance(z_lo, wp.array) and not isinstance(z_hi, wp.array):
            if np.any(hi.numpy() < lo.numpy()):
                raise ValueError("z_hi must be >= z_lo everywhere")
        b = lo.shape[0]
        if b > self.max_batch:
            raise ValueError(f"batch of {b} maps exceeds max_batch = {self.max_batch}")
        if self.pushed + b > self.num_maps:
            raise ValueError(f"pushing {b} maps would exceed num_maps = {self.num_maps} ({self.pushed} pushed)")
        if b == 0:
            return
        self.peak_working_bytes = max(self.peak_working_bytes, self.working_bytes + lo.capacity + hi.capacity)
        parallel.launch_rows(
            compress_batch_kernel, self.num_texels,
            [lo, hi, self.pushed, self.num_maps - 1, self._state],
            self.device, threads=self.threads, min_chunk=256,
        )
        self.pushed += b
        counts = self._state.out_count.numpy()
        total = int(counts.sum())
        if total:
            mask = np.arange(self.max_batch + 1)[None, :] < counts[:, None]
            depth = self._state.out_depth.numpy()[mask]  # texel-major, time order within a texel
            end = self._state.out_end.numpy()[mask]
            texel = np.repeat(np.arange(self.num_texels, dtype=np.int32), counts)
            self._chunks.append((texel, depth, end))
            self._counts += counts
        self.seconds += time.perf_counter() - t0

    @property
    def done(self) -> bool:
        """True once all ``num_maps`` maps were pushed."""
        return self.pushed == self.num_maps

    def finish(self) -> SegmentLists:
        """Assemble the per-batch chunks into per-texel segment lists (counting sort, O(output)); ValueError before
        all ``num_maps`` maps were pushed."""
        if not self.done:
            raise ValueError(f"finish() after {self.pushed} of {self.num_maps} maps")
        t0 = time.perf_counter()
        total = int(self._counts.sum())
        if total > 2**31 - 1:
            raise ValueError(f"{total} segments exceed the int32 lookup texture")
        start = np.zeros(self.num_texels + 1, dtype=np.int64)
        np.cumsum(self._counts, out=start[1:])
        seg_depth = np.empty(total, dtype=np.float32)
        seg_end = np.empty(total, dtype=np.int32)
        cursor = start[:-1].copy()
        while self._chunks:
            texel, depth, end = self._chunks.pop(0)
            # rank of each segment within its texel's group in this chunk (groups are contiguous)
            group_first = np.flatnonzero(np.r_[True, texel[1:] != texel[:-1]])
            group_len = np.diff(np.r_[group_first, texel.size])
            rank = np.arange(texel.size) - np.repeat(group_first, group_len)
            pos = cursor[texel] + rank
            seg_depth[pos] = depth
            seg_end[pos] = end
            cursor[texel[group_first]] += group_len
        self.seconds += time.perf_counter() - t0
        return SegmentLists(seg_start=start.astype(np.int32), seg_depth=seg_depth, seg_end=seg_end,
                            num_maps=self.num_maps)

    def stats(self, lists: SegmentLists) -> CompressionStats:
        """Sizes and costs of a finished compression."""
        s = int(lists.seg_depth.size)
        return CompressionStats(
            num_maps=self.num_maps, num_texels=self.num_texels, num_segments=s,
            compressed_bytes=8 * s + 4 * (self.num_texels + 1), uncompressed_bytes=4 * self.num_maps * self.num_texels,
            peak_working_bytes=int(self.peak_working_bytes), seconds_compress=self.seconds,
        )


def compress_depth_maps(z_lo, z_hi, batch_maps: int = 64, device: str | None = None) -> SegmentLists:
    """Compress a whole in-memory depth-map sequence (:class:`StreamingCompressor`, ``batch_maps`` maps at a time,
    which the result does not depend on): ``z_lo``, ``z_hi`` as for :meth:`StreamingCompressor.push`."""
    lo = np.asarray(z_lo, dtype=np.float32)
    hi = np.asarray(z_hi, dtype=np.float32)
    if lo.shape != hi.shape or lo.ndim not in (2, 3) or lo.shape[0] < 1:
        raise ValueError(f"z_lo and z_hi must have equal shapes (N, M, M) or (N, M^2), got {lo.shape}, {hi.shape}")
    n = lo.shape[0]
    texels = int(np.prod(lo.shape[1:]))
    batch_maps = _check_count("batch_maps", batch_maps)
    comp = StreamingCompressor(texels, n, min(batch_maps, n), device)
    for s in range(0, n, comp.max_batch):
        comp.push(lo[s: s + comp.max_batch], hi[s: s + comp.max_batch])
    return comp.finish()


@dataclass
class CoherentShadowMap:
    """A compressed depth-map set of one object: ``"latlong"`` orthographic maps (Sec. 4.1, 4.3) or ``"cube"`` maps
    at the samples of a fixed local light, 6N maps face by face (Sec. 3.3, 4.2).

    Attributes:
        kind: ``"latlong"`` or ``"cube"``.
        n1, n2, resolution, center, radius, enumeration, depth_layers, far, map_index: as
            :class:`~warpscatter.csm.depthmaps.LatLongMapSet` (lat-long maps span [-R, R]^2 and depths [0, 2R]) or
            :class:`~warpscatter.csm.depthmaps.CubeMapSet` (n1 x n2 light samples).
        lists, stats: the compressed :class:`SegmentLists`; :class:`CompressionStats` of the build (None when loaded).
        light_samples, near: cube only: (n1 n2, 3) sample positions (entry b n1 + a) and the faces' near plane.
        geometry: :func:`geometry_digest` of the source mesh (None if not stored).
    """

    n1: int
    n2: int
    resolution: int
    center: np.ndarray
    radius: float
    enumeration: str
    depth_layers: str
    far: str
    map_index: np.ndarray
    lists: SegmentLists
    stats: CompressionStats | None = None
    kind: str = KIND_LATLONG
    light_samples: np.ndarray | None = None
    near: float | None = None
    geometry: str | None = None
    _device_cache: dict = field(default_factory=dict, repr=False)

    @property
    def num_cells(self) -> int:
        """Cells of the location grid, n1 n2."""
        return self.n1 * self.n2

    @property
    def num_maps(self) -> int:
        """N = n1 n2 (lat-long) or 6 n1 n2 (cube)."""
        return self.num_cells * (6 if self.kind == KIND_CUBE else 1)

    @property
    def num_segments(self) -> int:
        return int(self.lists.seg_depth.size)

    @property
    def frames(self) -> np.ndarray:
        """Lat-long: (n1 n2, 3, 3) float64 rows (right, up, dir) per grid cell b * n1 + a."""
        return latlong_frames(self.n1, self.n2)

    def params(self) -> dict:
        """The scalar parameters (what :func:`save_csm` writes as JSON)."""
        out = {
            "kind": self.kind, "n1": self.n1, "n2": self.n2, "resolution": self.resolution,
            "center": [float(x) for x in self.center], "radius": float(self.radius),
            "enumeration": self.enumeration, "depth_layers": self.depth_layers, "far": self.far,
            "num_segments": self.num_segments,
        }
        if self.kind == KIND_CUBE:
            out["near"] = float(self.near)
        if self.geometry is not None:
            out["geometry"] = str(self.geometry)
        return out


def build_settings(settings: CSMBuildSettings | None = None, **fields) -> CSMBuildSettings:
    """``settings`` (default: ``render.lighting.csm``'s) with ``fields`` replaced; ValueError for an unknown field."""
    unknown = sorted(set(fields) - set(CSMBuildSettings.model_fields))
    if unknown:
        raise ValueError(f"unknown CSM build settings {unknown}; fields are {sorted(CSMBuildSettings.model_fields)}")
    return (CSMBuildSettings() if settings is None else settings).model_copy(update=fields)


def build_csm(
    vertices,
    triangles,
    settings: CSMBuildSettings | None = None,
    *,
    center=None,
    radius: float | None = None,
    progress: Callable[[float], None] | None = None,
    device: str | None = None,
    threads: int | None = None,
    **fields,
) -> CoherentShadowMap:
    """Render the lat-long depth-map set of a mesh batch by batch and compress it as it streams: a
    :class:`CoherentShadowMap` with its :class:`CompressionStats`.

    Args:
        vertices, triangles: (V, 3) object-space positions and (T, 3) vertex indices.
        settings: :class:`~warpscatter.csm.settings.CSMBuildSettings` (``maps``, ``resolution``, ``enumeration``,
            ``layers``, ``far``, ``batch``).
        center, radius: bounding sphere (default: fitted to the vertices).
        progress: called as ``progress(fraction)`` after each batch, fraction of maps done.
        device, threads: Warp device and CPU worker threads.
        **fields: fields replacing those of ``settings``, e.g. ``maps=(64, 32)``.
    """
    s = build_settings(settings, **fields)
    batch_maps = _check_batch(s.batch, progress)
    device = default_device(device)
    n1, n2 = s.maps
    maps = LatLongMapSet.create(vertices, triangles, n1=n1, n2=n2, resolution=s.resolution, enumeration=s.enumeration,
                                depth_layers=s.layers, far=s.far, center=center, radius=radius)
    return _build(maps, vertices, triangles, batch_maps, progress, device, threads)


def _check_batch(batch_maps, progress) -> int:
    batch_maps = _check_count("batch_maps", batch_maps)
    if progress is not None and not callable(progress):
        raise ValueError("progress must be callable as progress(fraction)")
    return batch_maps


def _build(maps, vertices, triangles, batch_maps: int, progress, device: str, threads,
           **kind_fields) -> CoherentShadowMap:
    """Render ``maps`` batch by batch in sequence order, compress them as they stream, return the CSM."""
    n = maps.num_maps
    batch = min(int(batch_maps), n)
    comp = StreamingCompressor(maps.num_texels, n, batch, device, threads)
    render_s = 0.0
    for s in range(0, n, batch):
        e = min(s + batch, n)
        t0 = time.perf_counter()
        if isinstance(maps, LatLongMapSet):
            z_lo, z_hi = maps.render_device(s, e, device, threads)
            working = maps.last_working_bytes
        else:
            z_lo, z_hi = maps.render(s, e, device)
            working = z_lo.nbytes + z_hi.nbytes + 12 * maps.num_texels * DEPTH_LAYERS[maps.depth_layers]
        render_s += time.perf_counter() - t0
        comp.peak_working_bytes = max(comp.peak_working_bytes, comp.working_bytes + working)
        comp.push(z_lo, z_hi)
        del z_lo, z_hi
        if progress is not None:
            progress(e / n)
    lists = comp.finish()
    stats = comp.stats(lists)
    stats.seconds_render = render_s
    return CoherentShadowMap(
        n1=maps.n1, n2=maps.n2, resolution=maps.resolution, center=maps.center, radius=maps.radius,
        enumeration=maps.enumeration, depth_layers=maps.depth_layers, far=maps.far, map_index=maps.map_index,
        lists=lists, stats=stats, geometry=geometry_digest(vertices, triangles), **kind_fields,
    )


def build_cube_csm(
    vertices,
    triangles,
    samples,
    settings: CSMBuildSettings | None = None,
    *,
    near: float | None = None,
    progress: Callable[[float], None] | None = None,
    device: str | None = None,
    **fields,
) -> CoherentShadowMap:
    """Compress the depth cube maps of a fixed local light (Sec. 3.3, 4.2), streaming in batches, into a
    :class:`CoherentShadowMap` of kind ``"cube"``.

    Args:
        vertices, triangles, progress, device, **fields: as for :func:`build_csm`.
        samples: (n2, n1, 3) light sample grid or (n, 3) row.
        settings: as for :func:`build_csm` (``resolution`` is the face size M; ``maps`` is not read).
        near: near-plane distance (default 1e-3 R).
    """
    s = build_settings(settings, **fields)
    batch_maps = _check_batch(s.batch, progress)
    device = default_device(device)
    maps = CubeMapSet.create(vertices, triangles, samples, resolution=s.resolution, enumeration=s.enumeration,
                             depth_layers=s.layers, far=s.far, near=near)
    return _build(maps, vertices, triangles, batch_maps, progress, device, None, kind=KIND_CUBE,
                  light_samples=maps.samples, near=maps.near)


def save_csm(csm: CoherentShadowMap, path: str | os.PathLike) -> None:
    """Write a CSM as one ``.npz`` (format version, JSON parameters, arrays), atomically: a unique temporary
    beside it, removed on failure or interruption, renamed in under the file's writer lock
    (:func:`..io.images.write_file_atomic`; ImageWriteError, an OSError, naming the file)."""
    from ..io.images import write_file_atomic

    extra = {}
    if csm.kind == KIND_CUBE:
        extra["light_samples"] = np.asarray(csm.light_samples, dtype=np.float64)

    def write(tmp) -> None:
        with open(tmp, "wb") as f:  # a file object: np.savez adds no ".npz" to the temporary's name
            np.savez(
                f, format_version=np.array(FORMAT_VERSION, dtype=np.int64),
                params=np.array(json.dumps(csm.params())), map_index=csm.map_index.astype(np.int32),
                seg_start=csm.lists.seg_start.astype(np.int32), seg_depth=csm.lists.seg_depth.astype(np.float32),
                seg_end=csm.lists.seg_end.astype(np.int32), **extra,
            )

    write_file_atomic(os.fspath(path), write)


#: Names of the CSM file reader that lived here before :mod:`.files` took it (issue #52).
_MOVED_TO_FILES = frozenset({"CSMFileError", "MAX_CSM_BYTES", "load_csm"})


def __getattr__(name: str):
    """``compress.load_csm`` and the reader's other old names: :mod:`.files`'s, with a DeprecationWarning (an import
    at the top would be a cycle: :mod:`.files` imports this module)."""
    if name not in _MOVED_TO_FILES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from ..moved import moved_attribute

    return moved_attribute(__name__, "warpscatter.csm.files", name)
