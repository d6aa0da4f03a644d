"""Epipolar lines on the device (Engelhardt & Dachsbacher 2010, Sec. 5.1-5.2): the coordinate texture, the camera
depth at every texel, the discontinuity search and the classification into ray-marching and interpolation samples.

Textures are (lines, samples) in the paper's layout (Fig. 6): row = line, column = position along it from the
epipole side; radiance and camera depth share one vec4 texture (one read per bilateral tap). The per-texel kernels
run one thread per line.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import warp as wp

from ...runtime.device import default_device, module_options
from ...runtime.parallel import launch_rows
from ...scene.camera import CameraParams, pixel_ray_direction
from ...scene.lights import LIGHT_DIRECTIONAL, LightParams, SpotLight, light_params
from .lines import EpipolarLines

module_options()


@wp.struct
class EpipolarGeometry:
    """The line layout as kernels see it (pixels, y down)."""

    epipole: wp.vec2  # screen position of the (anti-)epipole
    border_width: float  # border rectangle [0.5, 0.5 + border_width] x [0.5, 0.5 + border_height], pixels
    border_height: float
    spacing: float  # border arclength between consecutive lines' end points, pixels
    lines: int  # N: rows of the textures
    samples: int  # texels per line: their columns
    segment: int  # texels per initial segment


#: One line's segment as the upsampling reads it: entry (x, y), exit - entry (x, y), |exit - entry|^2,
#: |exit - entry|, valid (1 or 0), unused.
LineRecord = wp.types.vector(length=8, dtype=wp.float32)


@wp.struct
class LineArrays:
    """The per-line textures the upsampling reads, as kernels see them (:meth:`LineTextures.arrays`)."""

    entry: wp.array(dtype=wp.vec2)  # (N,) segment start (epipole side), pixels
    exit_: wp.array(dtype=wp.vec2)  # (N,) segment end (border side)
    valid: wp.array(dtype=wp.int32)  # (N,) 0 for culled lines
    depth: wp.array2d(dtype=wp.float32)  # (N, samples) camera depth at each texel
    radiance: wp.array2d(dtype=wp.vec3)  # (N, samples) L_scat at each texel
    records: wp.array(dtype=LineRecord)  # (N,) the segment as the per-pixel projections read it
    texels: wp.array(dtype=wp.vec4)  # (N * samples,) (L_scat, camera depth) at each texel, flat: one read per texel


# ---- building blocks (public @wp.func API) -------------------------------------------------------


@wp.func
def depth_discontinuity(a: float, b: float, threshold: float) -> bool:
    """A depth discontinuity between camera depths a and b: |a - b| > threshold min(a, b) (Engelhardt 2010 Sec. 5.2,
    6)."""
    return wp.abs(a - b) > threshold * wp.min(a, b)


@wp.func
def sample_distance(distance: wp.array2d(dtype=wp.float32), x: float, y: float, threshold: float) -> float:
    """Camera depth at screen point (x, y): bilinear between the 4 nearest pixel centres when they are
    continuous (no pair differs by more than ``threshold`` relative; linear extrapolation outside the outermost
    centres), else the nearest pixel's. Needs an image of at least 2 x 2 pixels."""
    h = distance.shape[0]
    w = distance.shape[1]
    fx = x - 0.5
    fy = y - 0.5
    i0 = wp.clamp(int(wp.floor(fx)), 0, w - 2)
    j0 = wp.clamp(int(wp.floor(fy)), 0, h - 2)
    i1 = i0 + 1
    j1 = j0 + 1
    d00 = distance[j0, i0]
    d10 = distance[j0, i1]
    d01 = distance[j1, i0]
    d11 = distance[j1, i1]
    lo = wp.min(wp.min(d00, d10), wp.min(d01, d11))
    hi = wp.max(wp.max(d00, d10), wp.max(d01, d11))
    if not depth_discontinuity(lo, hi, threshold):
        ax = fx - float(i0)
        ay = fy - float(j0)
        v = (d00 * (1.0 - ax) + d10 * ax) * (1.0 - ay) + (d01 * (1.0 - ax) + d11 * ax) * ay
        return wp.max(v, 0.5 * lo)  # extrapolation never leaves the surface's depth range by more than 2x
    ni = wp.clamp(int(wp.floor(x)), 0, w - 1)
    nj = wp.clamp(int(wp.floor(y)), 0, h - 1)
    return distance[nj, ni]


@wp.func
def border_arclength(e: wp.vec2, d: wp.vec2, width: float, height: float) -> float:
    """Border arclength (clockwise from the top-left corner, pixels) where the ray e + t d, t > 0, leaves the
    rectangle [0, width] x [0, height], which it must cross (Engelhardt 2010 Fig. 8); e relative to (0.5, 0.5)."""
    tx = float(1.0e30)
    ty = float(1.0e30)
    if d[0] > 0.0:
        tx = (width - e[0]) / d[0]
    elif d[0] < 0.0:
        tx = -e[0] / d[0]
    if d[1] > 0.0:
        ty = (height - e[1]) / d[1]
    elif d[1] < 0.0:
        ty = -e[1] / d[1]
    if tx < ty:
        y = wp.clamp(e[1] + tx * d[1], 0.0, height)
        if d[0] > 0.0:
            return width + y  # right edge, downwards
        return 2.0 * width + 2.0 * height - y  # left edge, upwards
    x = wp.clamp(e[0] + ty * d[0], 0.0, width)
    if d[1] > 0.0:
        return 2.0 * width + height - x  # bottom edge, leftwards
    return x  # top edge, rightwards


@wp.func
def ray_enters_cone(origin: wp.vec3, d: wp.vec3, apex: wp.vec3, axis: wp.vec3, cos_cone: float) -> bool:
    """True if the ray origin + t d (unit d, t >= 0) enters the forward cone of unit ``axis`` at ``apex`` with half
    angle acos(cos_cone) > 0: seen from the apex the ray sweeps a great-circle arc from normalize(origin - apex) to d,
    and it enters iff the arc comes within the half angle of the axis."""
    w = origin - apex
    lw = wp.length(w)
    if lw < 1.0e-12:
        return True
    u0 = w / lw
    best = wp.max(wp.dot(u0, axis), wp.dot(d, axis))
    m = wp.cross(u0, d)
    lm = wp.length(m)
    if lm > 1.0e-9:
        m = m / lm
        am = wp.dot(axis, m)
        q = axis - m * am
        lq = wp.length(q)
        if lq > 1.0e-9:
            q = q / lq
            if wp.dot(wp.cross(u0, q), m) >= 0.0 and wp.dot(wp.cross(q, d), m) >= 0.0:
                best = wp.max(best, wp.sqrt(wp.max(1.0 - am * am, 0.0)))
    return best >= cos_cone


@wp.func
def screen_point_in_light(cam: CameraParams, light: LightParams, p: wp.vec2) -> bool:
    """True if the camera ray through screen point p (pixels) enters the light's frustum (always for directional
    lights; for spot lights the cone of :func:`~warpscatter.scene.lights.light_sample`)."""
    if light.kind == LIGHT_DIRECTIONAL:
        return True
    d = pixel_ray_direction(cam, p[0], p[1])
    return ray_enters_cone(cam.position, d, light.position, light.direction, light.cos_cone)


@wp.func
def cone_edge(cam: CameraParams, light: LightParams, a: wp.vec2, ab: wp.vec2, t_in: float, t_out: float) -> float:
    """Where the screen segment a + t ab leaves the light frustum between t_in (inside) and t_out (outside): the
    outside end of 24 bisection steps' bracket, so the edge stays covered."""
    for _it in range(24):
        mid = 0.5 * (t_out + t_in)
        if screen_point_in_light(cam, light, a + ab * mid):
            t_in = mid
        else:
            t_out = mid
    return t_out


@wp.func
def project_on_line(a: wp.vec2, b: wp.vec2, p: wp.vec2) -> float:
    """Parameter tau of the orthogonal projection of p onto the line a + tau (b - a) (0 for a zero-length line)."""
    ab = b - a
    l2 = wp.dot(ab, ab)
    if l2 < 1.0e-12:
        return 0.0
    return wp.dot(p - a, ab) / l2


@wp.func
def wrap_line(k: int, n: int) -> int:
    """Line index k modulo n (non-negative)."""
    r = k
    if r < 0:
        r += n  # the common cases (-n <= k < 2n) without an integer division
    elif r >= n:
        r -= n
    if r < 0 or r >= n:
        r = k % n
        if r < 0:
            r += n
    return r


@wp.kernel
def trim_to_cone_kernel(
    cam: CameraParams,
    light: LightParams,
    points: int,
    entry: wp.array(dtype=wp.vec2),  # in/out: segment start
    exit_: wp.array(dtype=wp.vec2),  # in/out: segment end
    valid: wp.array(dtype=wp.int32),  # in/out: 0 when no camera ray of the segment enters the cone
    offset: int,
):
    # Engelhardt 2010 Sec. 5.1: a line's rays entering the cone form one interval: found on ``points`` points, both
    # ends refined by bisection, one pixel of margin
    k = wp.tid() + offset
    if valid[k] == 0:
        return
    a = entry[k]
    ab = exit_[k] - a
    first = int(-1)
    last = int(-1)
    for n in range(points):
        if screen_point_in_light(cam, light, a + ab * (float(n) / float(points - 1))):
            if first < 0:
                first = n
            last = n
    if first < 0:
        valid[k] = 0
        return
    dt = 1.0 / float(points - 1)
    t_lo = float(first) * dt
    if first > 0:
        t_lo = cone_edge(cam, light, a, ab, t_lo, t_lo - dt)
    t_hi = float(last) * dt
    if last < points - 1:
        t_hi = cone_edge(cam, light, a, ab, t_hi, t_hi + dt)
    pad = 1.0 / wp.max(wp.length(ab), 1.0e-6)
    t_lo = wp.max(t_lo - pad, 0.0)
    t_hi = wp.min(t_hi + pad, 1.0)
    entry[k] = a + ab * t_lo
    exit_[k] = a + ab * t_hi


@wp.kernel
def line_records_kernel(
    entry: wp.array(dtype=wp.vec2),
    exit_: wp.array(dtype=wp.vec2),
    valid: wp.array(dtype=wp.int32),
    records: wp.array(dtype=LineRecord),  # out
):
    # the per-line terms of project_on_line and of the segment length, computed once per line
    k = wp.tid()
    a = entry[k]
    ab = exit_[k] - a
    records[k] = LineRecord(a[0], a[1], ab[0], ab[1], wp.dot(ab, ab), wp.length(ab), float(valid[k]), 0.0)


@wp.kernel
def line_samples_kernel(
    geo: EpipolarGeometry,
    entry: wp.array(dtype=wp.vec2),
    exit_: wp.array(dtype=wp.vec2),
    valid: wp.array(dtype=wp.int32),
    distance: wp.array2d(dtype=wp.float32),
    threshold: float,
    coords: wp.array2d(dtype=wp.vec2),  # out: coordinate texture (line, texel) -> screen position
    line_depth: wp.array2d(dtype=wp.float32),  # out: camera depth at each texel
    offset: int,
):
    # Engelhardt 2010 Sec. 5.1: texel positions between the clipped segment's end points
    k = wp.tid() + offset
    n = geo.samples
    if valid[k] == 0:
        for x in range(n):
            coords[k, x] = wp.vec2(-1.0, -1.0)
            line_depth[k, x] = 0.0
        return
    a = entry[k]
    ab = exit_[k] - entry[k]
    for x in range(n):
        p = a + ab * (float(x) / float(n - 1))
        coords[k, x] = p
        line_depth[k, x] = sample_distance(distance, p[0], p[1], threshold)


@wp.kernel
def discontinuity_kernel(
    geo: EpipolarGeometry,
    valid: wp.array(dtype=wp.int32),
    line_depth: wp.array2d(dtype=wp.float32),
    threshold: float,
    coords: wp.array2d(dtype=wp.vec2),  # the texels' screen positions
    dense_radius: float,  # texels within this many pixels of the epipole are all ray-marching samples (0: none)
    interp: wp.array2d(dtype=wp.vec2i),  # out: interpolation texture (left, right source texels)
    march: wp.array(dtype=wp.int32),  # out: 1 for ray-marching samples, flat index line * samples + texel
    marched: wp.array2d(dtype=wp.int32),  # out: the line's ray-marching texels in order (the first count[k])
    count: wp.array(dtype=wp.int32),  # out: ray-marching samples per line
    offset: int,
):
    # Engelhardt 2010 Sec. 5.2 in one pass per line: an initial segment splits into runs at depth discontinuities;
    # a run [a, b]'s texels get the sources (a, b) (what the paper's per-texel search finds), marched samples
    k = wp.tid() + offset
    n = geo.samples
    row = k * n
    if valid[k] == 0:
        for x in range(n):
            interp[k, x] = wp.vec2i(x, x)
            march[row + x] = 0
        count[k] = 0
        return
    c = int(0)
    seg = geo.segment
    for x0 in range(0, n - 1, seg):
        end = x0 + seg  # the segment's last texel (the next segment's first)
        a = x0
        d_next = line_depth[k, x0]
        for x in range(x0, end + 1):
            d = d_next
            cut = x == end
            if not cut:
                d_next = line_depth[k, x + 1]
                cut = depth_discontinuity(d, d_next, threshold)
                if dense_radius > 0.0 and (wp.length(coords[k, x] - geo.epipole) < dense_radius
                                           or wp.length(coords[k, x + 1] - geo.epipole) < dense_radius):
                    cut = True  # around a spot's own image: every texel its own run (see classify_samples)
            if cut:  # the run [a, x] ends here
                for y in range(a, wp.min(x + 1, end)):
                    interp[k, y] = wp.vec2i(a, x)
                    march[row + y] = 0
                if a < end:
                    march[row + a] = 1
                    marched[k, c] = a
                    c += 1
                if x > a and x < end:
                    march[row + x] = 1
                    marched[k, c] = x
                    c += 1
                a = x + 1
    # the last texel closes the last segment and is its own source
    interp[k, n - 1] = wp.vec2i(n - 1, n - 1)
    march[row + n - 1] = 1
    marched[k, c] = n - 1
    count[k] = c + 1


@wp.kernel
def gather_rows_kernel(
    rows: wp.array2d(dtype=wp.int32),  # per row, the columns listed (the first count[r])
    count: wp.array(dtype=wp.int32),
    start: wp.array(dtype=wp.int32),  # exclusive prefix sum of count
    indices: wp.array(dtype=wp.int32),  # out: flat indices row * row_length + column, row-major
    offset: int,
):
    r = wp.tid() + offset
    s = start[r]
    for c in range(count[r]):
        indices[s + c] = r * rows.shape[1] + rows[r, c]


@wp.kernel
def compact_kernel(flags: wp.array(dtype=wp.int32), scan: wp.array(dtype=wp.int32),
                   indices: wp.array(dtype=wp.int32), offset: int):
    # scatter the flagged flat indices to their exclusive-scan slots (the paper's stencil mask as a list)
    n = wp.tid() + offset
    if flags[n] != 0:
        indices[scan[n]] = n


def compact(flags: wp.array, device=None) -> tuple[wp.array, int]:
    """(indices, count): the indices of the non-zero entries of a 1-D int32 flag array, in an int32 array of length
    max(count, 1) (exclusive scan + scatter)."""
    device = default_device(device)
    n = flags.shape[0]
    scan = wp.empty(n, dtype=wp.int32, device=device)
    wp.utils.array_scan(flags, scan, inclusive=False)
    count = int(scan[n - 1:].numpy()[0] + flags[n - 1:].numpy()[0]) if n else 0
    indices = wp.empty(max(count, 1), dtype=wp.int32, device=device)
    if count:
        launch_rows(compact_kernel, n, [flags, scan, indices], device=device)
    return indices, count


def gather_rows(rows: wp.array, count: wp.array, device=None) -> tuple[wp.array, int]:
    """(indices, total): the flat indices ``row * rows.shape[1] + column``, row-major, of the first ``count[r]``
    columns listed in each row r of ``rows`` (R, C), in an int32 array of length max(total, 1)."""
    device = default_device(device)
    counts = count.numpy().astype(np.int64)
    total = int(counts.sum())
    indices = wp.empty(max(total, 1), dtype=wp.int32, device=device)
    if total:
        start = np.zeros(len(counts), dtype=np.int32)
        np.cumsum(counts[:-1], out=start[1:])
        launch_rows(gather_rows_kernel, len(counts), [rows, count, wp.array(start, dtype=wp.int32, device=device),
                                                      indices], device=device)
    return indices, total


def geometry_params(lines: EpipolarLines) -> EpipolarGeometry:
    """:class:`EpipolarGeometry` of a set of lines."""
    g = EpipolarGeometry()
    g.epipole = wp.vec2(float(lines.epipole[0]), float(lines.epipole[1]))
    g.border_width, g.border_height = float(lines.width - 1), float(lines.height - 1)
    g.spacing = float(lines.spacing)
    g.lines, g.samples, g.segment = int(lines.count), int(lines.samples), int(lines.segment)
    return g


@dataclass
class LineTextures:
    """Device textures of the epipolar lines, (lines, samples) in the paper's layout (Fig. 6); ``entry``, ``exit`` and
    ``valid`` as in :class:`LineArrays`, ``radiance`` and ``depth`` strided views of ``texels``."""

    entry: wp.array
    exit: wp.array
    valid: wp.array
    records: wp.array  # (N,) LineRecord: the segments as the upsampling reads them
    coords: wp.array  # coordinate texture: vec2 screen position
    texels: wp.array  # vec4 (L_scat, camera depth)
    depth: wp.array  # float32 view of texels: camera depth (G-buffer distance) at each texel
    radiance: wp.array  # vec3 view of texels: the radiance texture (L_scat; filled by ray marching + interpolation)
    interp: wp.array | None = None  # interpolation texture: vec2i (left, right) sources
    march: wp.array | None = None  # (N * samples,) int32: 1 for ray-marching samples
    samples: wp.array | None = None  # (max(sample_count, 1),) int32: flat indices of the ray-marching samples
    sample_count: int = 0  # ray-marching samples

    def arrays(self) -> LineArrays:
        """The textures the upsampling reads (:class:`LineArrays`); the radiance must be filled."""
        a = LineArrays()
        a.entry, a.exit_, a.valid, a.depth, a.radiance = self.entry, self.exit, self.valid, self.depth, self.radiance
        a.records, a.texels = self.records, self.texels.flatten()
        return a


#: Points per line at which the light frustum is tested before the bisection of :func:`trim_to_cone`.
CONE_TRIM_POINTS = 128


def trim_to_cone(lines: EpipolarLines, camera, light, device=None) -> EpipolarLines:
    """Clip the lines to a spot light's cone, one pixel of margin, culling lines that miss it (Engelhardt 2010 Sec.
    5.1); an interval narrower than 1 / CONE_TRIM_POINTS of a line may be missed (its pixels are then marched)."""
    if not isinstance(light, SpotLight):
        return lines
    device = default_device(device)
    entry = wp.array(lines.entry, dtype=wp.vec2, device=device)
    exit_ = wp.array(lines.exit, dtype=wp.vec2, device=device)
    valid = wp.array(lines.valid.astype(np.int32), dtype=wp.int32, device=device)
    launch_rows(trim_to_cone_kernel, lines.count,
                [camera.params(), light_params(light, device), CONE_TRIM_POINTS, entry, exit_, valid], device=device)
    return replace(lines, entry=entry.numpy(), exit=exit_.numpy(), valid=valid.numpy().astype(bool))


def texel_views(texels: wp.array) -> tuple[wp.array, wp.array]:
    """(radiance, depth): vec3 and float32 views of an (N, S) vec4 texture's (xyz, w), sharing its memory."""
    n, s = texels.shape
    strides = (s * 16, 16)
    radiance = wp.array(ptr=texels.ptr, dtype=wp.vec3, shape=(n, s), strides=strides, device=texels.device)
    depth = wp.array(ptr=texels.ptr + 12, dtype=wp.float32, shape=(n, s), strides=strides, device=texels.device)
    return radiance, depth


def line_samples(lines: EpipolarLines, distance: wp.array, depth_threshold: float, device=None) -> LineTextures:
    """Coordinate texture and per-texel camera depth from the G-buffer ``distance`` (Engelhardt 2010 Sec. 5.1;
    :func:`sample_distance` with ``depth_threshold``)."""
    device = default_device(device)
    n, s = lines.count, lines.samples
    texels = wp.empty((n, s), dtype=wp.vec4, device=device)
    radiance, depth = texel_views(texels)
    tex = LineTextures(entry=wp.array(lines.entry, dtype=wp.vec2, device=device),
                       exit=wp.array(lines.exit, dtype=wp.vec2, device=device),
                       valid=wp.array(lines.valid.astype(np.int32), dtype=wp.int32, device=device),
                       records=wp.empty(n, dtype=LineRecord, device=device),
                       coords=wp.empty((n, s), dtype=wp.vec2, device=device),
                       texels=texels, depth=depth, radiance=radiance)
    wp.launch(line_records_kernel, n, [tex.entry, tex.exit, tex.valid, tex.records], device=device)
    launch_rows(line_samples_kernel, n,
                [geometry_params(lines), tex.entry, tex.exit, tex.valid, distance, float(depth_threshold), tex.coords,
                 tex.depth], device=device)
    return tex


def classify_samples(lines: EpipolarLines, tex: LineTextures, depth_threshold: float, device=None,
                     dense_radius: float = 0.0) -> LineTextures:
    """Discontinuity search and classification into ray-marching / interpolation samples (Sec. 5.2): fills
    ``tex.interp``, ``tex.march`` and ``tex.samples`` / ``tex.sample_count`` (the paper's stencil mask as a list).
    Every texel within ``dense_radius`` pixels of the epipole is marched (warpscatter's): a spot in front of the
    camera is its own epipole, where in-scattering falls off like 1 / distance and interpolation overshoots."""
    device = default_device(device)
    n, s = lines.count, lines.samples
    tex.interp = wp.empty((n, s), dtype=wp.vec2i, device=device)
    tex.march = wp.empty(n * s, dtype=wp.int32, device=device)
    marched = wp.empty((n, s), dtype=wp.int32, device=device)
    count = wp.empty(n, dtype=wp.int32, device=device)
    geo = geometry_params(lines)
    launch_rows(discontinuity_kernel, n,
                [geo, tex.valid, tex.depth, float(depth_threshold), tex.coords, float(dense_radius), tex.interp,
                 tex.march, marched, count],
                device=device)
    tex.samples, tex.sample_count = gather_rows(marched, count, device)
    return tex


def sample_texture_bytes(lines: EpipolarLines) -> int:
    """Bytes of the per-line textures (coordinate 8, radiance and depth 16, interpolation 8, flags 4 per texel)."""
    return int(lines.count * lines.samples * (8 + 16 + 8 + 4))


__all__ = [
    "CONE_TRIM_POINTS",
    "EpipolarGeometry",
    "LineArrays",
    "LineRecord",
    "LineTextures",
    "border_arclength",
    "classify_samples",
    "compact",
    "depth_discontinuity",
    "gather_rows",
    "geometry_params",
    "line_samples",
    "project_on_line",
    "ray_enters_cone",
    "sample_distance",
    "sample_texture_bytes",
    "screen_point_in_light",
    "texel_views",
    "trim_to_cone",
    "wrap_line",
]
