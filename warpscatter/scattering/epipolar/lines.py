"""Epipolar lines on the screen for epipolar sampling (Engelhardt & Dachsbacher 2010, Sec. 4.1 and 5.1): host geometry.

Per frame, in float64 numpy: the epipole (the light projected onto the image plane; a light behind the camera gives
the anti-crepuscular vanishing point, the same lines), the lines from it to ``lines`` equidistant border points
(clockwise from the top-left corner) clipped to the viewport (Liang-Barsky), and the texel layout: one texture row
per line, ``samples`` columns from the epipole side, every ``segment``-th an initial ray-marching sample. Screen
coordinates are pixels, x right, y DOWN, pixel (i, j) centred at (i + 0.5, j + 0.5) (CONVENTIONS.md); the border is
the rectangle through the outermost pixel centres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...scene.lights import DirectionalLight, SpotLight


@dataclass(frozen=True)
class EpipolarLines:
    """The epipolar lines of one frame (all positions in pixels, y down).

    Attributes:
        epipole: (2,) screen position of the (anti-)epipole, possibly far outside the image.
        light_behind: True when the light is behind the camera (the anti-crepuscular vanishing point).
        entry: (N, 2) float32 start of each line's visible segment: the epipole when inside the border rectangle, else
            where the line enters the rectangle grown by half a spacing.
        exit: (N, 2) float32 end of each segment, where it leaves the grown rectangle. Culled lines keep their
            unclipped epipole-to-border segment.
        valid: (N,) bool: the line crosses the viewport (and a spot's frustum), or was redirected to a corner
            (:func:`redirect_to_tangent_corners`).
        spacing: arclength between consecutive border points (pixels).
        samples: texels per line (columns of the textures).
        segment: texels per initial segment; texel x is an initial sample when x % segment == 0.
        width, height: image size in pixels.
    """

    epipole: np.ndarray
    light_behind: bool
    entry: np.ndarray
    exit: np.ndarray
    valid: np.ndarray
    spacing: float
    samples: int
    segment: int
    width: int
    height: int

    @property
    def count(self) -> int:
        return int(self.entry.shape[0])

    def texel_positions(self) -> np.ndarray:
        """(N, samples, 2) float64 screen position of every texel (the coordinate texture, computed on the host)."""
        t = np.arange(self.samples, dtype=np.float64) / (self.samples - 1)
        e, x = self.entry.astype(np.float64), self.exit.astype(np.float64)
        return e[:, None, :] + t[None, :, None] * (x - e)[:, None, :]


def texel_layout(width: int, height: int, initial_samples: int, samples_per_line: int | None) -> tuple[int, int]:
    """(texels per line, per initial segment): ``samples_per_line`` (None: the image diagonal in pixels) rounded up so
    that ``initial_samples`` equidistant initial samples fall on texels, the first and last included."""
    want = int(math.ceil(math.hypot(width, height))) if samples_per_line is None else int(samples_per_line)
    want = max(want, initial_samples)
    segment = max(1, int(math.ceil((want - 1) / (initial_samples - 1))))
    return (initial_samples - 1) * segment + 1, segment


def screen_direction(camera, light) -> tuple[np.ndarray, str | None]:
    """Unit world direction from the camera towards the light, or (None, reason) when it is undefined."""
    if isinstance(light, DirectionalLight):
        return -np.asarray(light.direction, np.float64), None
    v = np.asarray(light.position, np.float64) - np.asarray(camera.position, np.float64)
    scale = max(1.0, float(np.abs(camera.position).max()))
    n = float(np.linalg.norm(v))
    if n <= 1e-6 * scale:
        return None, "the spot light sits at the camera position: the epipole is undefined"
    return v / n, None


def project_epipole(camera, light, max_distance: float) -> tuple[np.ndarray | None, bool, str | None]:
    """(epipole, behind, reason): the (2,) pixel position of the light's (anti-)epipole, None with the reason when it
    is undefined or farther than ``max_distance`` image diagonals from the image centre (at infinity), and whether
    the light is behind the camera."""
    v, reason = screen_direction(camera, light)
    if v is None:
        return None, False, reason
    right, up, fwd = camera.basis
    z, x, y = float(v @ fwd), float(v @ right), float(v @ up)
    t = math.tan(math.radians(camera.fov_y) / 2.0)
    w, h = camera.width, camera.height
    # pixel offset of the epipole from the image centre, times z (finite even when z = 0)
    ox, oy = x / (t * camera.aspect) * w / 2.0, -y / t * h / 2.0
    diag = math.hypot(w, h)
    if math.hypot(ox, oy) > max_distance * diag * abs(z) or abs(z) < 1e-12:
        return None, z < 0.0, (f"the epipole is at infinity (direction to the light {np.round(v, 4).tolist()} "
                               f"nearly parallel to the image plane: farther than {max_distance:g} image diagonals)")
    return np.array([w / 2.0 + ox / z, h / 2.0 + oy / z]), z < 0.0, None


def border_rectangle(width: int, height: int) -> tuple[float, float]:
    """(w, h) of the border rectangle [0.5, 0.5 + w] x [0.5, 0.5 + h] through the outermost pixel centres."""
    return float(width - 1), float(height - 1)


def border_points(width: int, height: int, count: int) -> np.ndarray:
    """(count, 2) equidistant points on the border rectangle, clockwise from its top-left corner, half a spacing in
    (arclength as :func:`~.textures.border_arclength`)."""
    w, h = border_rectangle(width, height)
    s = (np.arange(count) + 0.5) * (2.0 * (w + h) / count)
    x = np.select([s < w, s < w + h, s < 2 * w + h], [s, w, 2 * w + h - s], 0.0)
    y = np.select([s < w, s < w + h, s < 2 * w + h], [0.0, s - w, h], 2 * (w + h) - s)
    return np.stack([x, y], axis=1) + 0.5


def clip_segments(start: np.ndarray, end: np.ndarray, width: int, height: int,
                  margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(t0, t1), the visible parameter range (t1 <= t0: none) of each segment start -> end clipped (Liang-Barsky) to
    the border rectangle [0.5, W - 0.5] x [0.5, H - 0.5] grown by ``margin`` pixels."""
    d = end - start
    t0 = np.zeros(len(start))
    t1 = np.ones(len(start))
    for axis, size in enumerate(border_rectangle(width, height)):
        hi = size + 2.0 * margin
        p, q0 = d[:, axis], start[:, axis] - 0.5 + margin  # relative to the grown rectangle's corner
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (0.0 - q0) / p, (hi - q0) / p
        lo_t, hi_t = np.minimum(ta, tb), np.maximum(ta, tb)
        parallel = p == 0.0
        outside = parallel & ((q0 < 0.0) | (q0 > hi))
        t0 = np.where(parallel, t0, np.maximum(t0, lo_t))
        t1 = np.where(parallel, t1, np.minimum(t1, hi_t))
        t1 = np.where(outside, -1.0, t1)
    return t0, t1


def pixel_directions(camera, points: np.ndarray) -> np.ndarray:
    """Unit world directions of camera rays through screen points (..., 2) in pixels (CONVENTIONS rays)."""
    t = math.tan(math.radians(camera.fov_y) / 2.0)
    right, up, fwd = camera.basis
    xn = (2.0 * points[..., 0] / camera.width - 1.0) * t * camera.aspect
    yn = (1.0 - 2.0 * points[..., 1] / camera.height) * t
    d = xn[..., None] * right + yn[..., None] * up + fwd
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def redirect_to_tangent_corners(border: np.ndarray, valid: np.ndarray, epipole: np.ndarray, width: int,
                                height: int) -> None:
    """Point the first culled line beyond each end of the visible chain at the corner seen tangentially from an
    epipole outside the border (in place): a pixel between the last valid line and that corner then lies within half
    a spacing of a valid line, and the line's index, hence the 1D border lookup, is unchanged."""
    bw, bh = border_rectangle(width, height)
    inside = 0.5 <= epipole[0] <= 0.5 + bw and 0.5 <= epipole[1] <= 0.5 + bh
    if inside or not valid.any() or valid.all():
        return
    n = len(valid)
    perimeter = 2.0 * (bw + bh)
    s = (np.arange(n) + 0.5) * (perimeter / n)
    corner_s = np.array([0.0, bw, bw + bh, 2.0 * bw + bh])
    corner_xy = np.array([[0.0, 0.0], [bw, 0.0], [bw, bh], [0.0, bh]]) + 0.5
    ends = np.nonzero(valid & ~np.roll(valid, -1))[0]  # chain ends after line k
    starts = np.nonzero(valid & ~np.roll(valid, 1))[0]  # chain starts at line k
    for k in ends:
        c = int(np.argmin((corner_s - s[k]) % perimeter))  # first corner after the last valid border point
        border[(k + 1) % n] = corner_xy[c]
        valid[(k + 1) % n] = True
    for k in starts:
        c = int(np.argmin((s[k] - corner_s) % perimeter))  # last corner before the first valid border point
        border[(k - 1) % n] = corner_xy[c]
        valid[(k - 1) % n] = True


def epipolar_lines(camera, light, lines: int, initial_samples: int, samples_per_line: int | None = None,
                   max_epipole_distance: float = 1000.0) -> tuple[EpipolarLines | None, str | None]:
    """(:class:`EpipolarLines`, None), or (None, reason) when the epipole is at infinity or undefined: the frame's
    ``lines`` lines, generated, clipped and culled (Engelhardt 2010 Sec. 4.1, 5.1), their layout by
    :func:`texel_layout`; ``max_epipole_distance`` as :func:`project_epipole`'s."""
    epipole, behind, reason = project_epipole(camera, light, max_epipole_distance)
    if epipole is None:
        return None, reason
    w, h = camera.width, camera.height
    samples, segment = texel_layout(w, h, initial_samples, samples_per_line)
    border = border_points(w, h, lines)
    start = np.broadcast_to(epipole, border.shape).astype(np.float64)
    d = border - start
    t0, t1 = clip_segments(start, border, w, h)
    valid = (t1 - t0) * np.linalg.norm(d, axis=1) > 1e-3
    redirect_to_tangent_corners(border, valid, epipole, w, h)
    d = border - start
    # a pixel between two lines' end points projects onto them up to half a spacing beyond the border: each line runs
    # on to the rectangle grown by half a spacing (depth extrapolated there); validity is decided on the rectangle
    spacing = 2.0 * sum(border_rectangle(w, h)) / lines
    margin = 0.5 * spacing + 0.5
    reach = 1.0 + 2.0 * (math.hypot(w, h) + 2.0 * margin) / np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    g0, g1 = clip_segments(start, start + reach[:, None] * d, w, h, margin=margin)
    t0 = np.where(valid, g0 * reach, 0.0)
    t1 = np.where(valid, g1 * reach, 1.0)
    entry = start + t0[:, None] * d
    exit_ = start + t1[:, None] * d
    return EpipolarLines(epipole=epipole, light_behind=bool(behind), entry=entry.astype(np.float32),
                         exit=exit_.astype(np.float32), valid=valid, spacing=spacing,
                         samples=samples, segment=segment, width=w, height=h), None


def light_texture_level(lines: EpipolarLines, camera, light, texture_shape) -> tuple[int, float]:
    """(level, footprint in texels) of a spot light's texture matched to the lines' angular spacing (Sec. 6): adjacent
    epipolar planes differ by a dihedral angle dphi about the baseline (the median over valid neighbours), which moves
    texture detail at angle psi from it by dphi sin(psi); the footprint is dphi max(sin psi, sin cone) W /
    (2 tan cone), psi the spot axis' angle to the baseline, and the level floor(log2(footprint)) (0 up to a texel)."""
    if not isinstance(light, SpotLight) or lines.count < 2:
        return 0, 0.0
    baseline = np.asarray(camera.position, np.float64) - np.asarray(light.position, np.float64)
    nb = np.linalg.norm(baseline)
    if nb <= 0.0:
        return 0, 0.0
    n = np.cross(baseline, pixel_directions(camera, lines.exit.astype(np.float64)))
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    pair = lines.valid & np.roll(lines.valid, -1)
    if not pair.any():
        return 0, 0.0
    dphi = np.arccos(np.clip(np.einsum("ij,ij->i", n, np.roll(n, -1, axis=0)), -1.0, 1.0))[pair]
    cone = math.radians(light.cone_deg)
    sin_psi = float(np.linalg.norm(np.cross(baseline / nb, light.direction)))
    footprint = float(np.median(dphi)) * max(sin_psi, math.sin(cone)) * max(texture_shape[:2]) / (2 * math.tan(cone))
    if footprint <= 1.0:
        return 0, footprint
    top = int(math.floor(math.log2(max(texture_shape[:2]))))
    return min(int(math.floor(math.log2(footprint))), top), footprint
