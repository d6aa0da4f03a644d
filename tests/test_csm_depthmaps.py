"""CSM depth-map sets: batched depth peeling equals the rasterizer, linear depths, far planes, lat-long frames."""

import numpy as np
import pytest
import trimesh
import warp as wp

from warpscatter.csm.depthmaps import (
    LatLongMapSet,
    bounding_sphere,
    latlong_direction,
    latlong_frames,
    latlong_param,
)
from warpscatter.raster import rasterizer as raster
from warpscatter.raster.raycast import build_mesh, raycast_depth


def bumpy_mesh_with_moon():
    """A closed bumpy icosphere (concave dents) plus a small box beside it: up to 4 surfaces per ray, and
    texels that see nothing."""
    s = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(s.vertices, np.float64)
    v *= (1.0 + 0.3 * np.sin(3.0 * v[:, 0]) * np.sin(2.0 * v[:, 1] + 1.0))[:, None]
    box = trimesh.creation.box(extents=[0.4, 0.4, 0.4])
    bv = np.asarray(box.vertices) + [1.7, 0.2, 0.0]
    verts = np.vstack([v, bv]).astype(np.float32)
    tris = np.vstack([s.faces, box.faces + len(v)]).astype(np.int32)
    return verts, tris


def key_depths(keys: np.ndarray, radius: float) -> np.ndarray:
    """Linear depths from raster's packed keys: float32 depth01 bits * 2R, +inf where empty."""
    bits = (keys >> 32).astype(np.uint32)
    d01 = bits.view(np.float32)
    return np.where(keys == raster.EMPTY_KEY, np.inf, d01 * np.float32(2.0 * radius)).astype(np.float32)


@pytest.mark.parametrize("depth_layers", ["z1z2", "z1z3"])
def test_batched_peeling_equals_rasterize(depth_layers):
    v, t = bumpy_mesh_with_moon()
    maps = LatLongMapSet.create(v, t, n1=6, n2=4, resolution=24, depth_layers=depth_layers, far="infinite")
    z_lo, z_hi = maps.render(0, maps.num_maps)
    hi_layer = 1 if depth_layers == "z1z2" else 2
    assert np.isfinite(z_hi).sum() > 100  # the upper layer is populated (z1z3: 3+ surfaces occur)
    for i in (0, 7, 23):
        r = raster.rasterize(v, t, maps.view_proj(i), 24, 24, layers=3, clamp_depth=True)
        ref = key_depths(r.keys.numpy(), maps.radius)
        assert np.array_equal(z_lo[i], ref[0])  # bitwise
        assert np.array_equal(z_hi[i], ref[hi_layer])


def test_depth_is_linear_distance_from_the_map_plane():
    v, t = bumpy_mesh_with_moon()
    maps = LatLongMapSet.create(v, t, n1=4, n2=3, resolution=32)
    z_lo, _ = maps.render(0, maps.num_maps)
    mesh = build_mesh(v, t)
    for i in (1, 6, 10):
        ndc = raycast_depth(mesh, maps.view_proj(i), 32, 32).ndc_depth[0]
        ref = (ndc.astype(np.float64) + 1.0) * maps.radius  # orthographic: NDC depth is linear
        both = np.isfinite(ref) & np.isfinite(z_lo[i])
        assert np.mean(np.isfinite(ref) == np.isfinite(z_lo[i])) > 0.99  # measured 1.0 (edge ties aside)
        err = (ref[both] - z_lo[i][both]) / maps.radius
        # The rasterizer interpolates depth at vertices snapped to 1/1024 texel: small errors, no offset.
        assert abs(np.mean(err)) < 2e-5  # measured <= 6.2e-6
        assert np.median(np.abs(err)) < 3e-5  # measured <= 1.0e-5
        assert np.max(np.abs(err)) < 1e-3  # measured 2.4e-4 (steep triangles)


def test_far_modes_on_a_single_sheet():
    # A square sheet: one surface per ray, so the upper depth is the far value everywhere it is hit.
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    t = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    m = 16
    for far in ("sphere", "infinite"):
        maps = LatLongMapSet.create(v, t, n1=4, n2=2, resolution=m, far=far)
        z_lo, z_hi = maps.render(0, 8)
        hit = np.isfinite(z_lo)
        assert hit.any() and (~hit).any()
        assert np.all(np.isinf(z_hi[~hit]))  # empty texels: z_lo = z_hi = +inf
        if far == "infinite":
            assert np.all(np.isinf(z_hi[hit]))
        else:
            x = 2.0 * (np.arange(m) + 0.5) / m - 1.0
            r2 = x[None, :] ** 2 + x[:, None] ** 2
            exit_depth = maps.radius * (1.0 + np.sqrt(np.maximum(1.0 - r2, 0.0)))
            expect = np.maximum(np.broadcast_to(exit_depth, z_lo.shape)[hit], z_lo[hit])
            np.testing.assert_allclose(z_hi[hit], expect, rtol=1e-6)  # float32 evaluation of the same formula
            assert np.all(z_hi[hit] >= z_lo[hit])


@wp.kernel
def _directions_kernel(n1: int, n2: int, out: wp.array(dtype=wp.vec3), uv: wp.array(dtype=wp.vec2)):
    a, b = wp.tid()
    d = latlong_direction((float(a) + 0.5) / float(n1), (float(b) + 0.5) / float(n2))
    out[b * n1 + a] = d
    uv[b * n1 + a] = latlong_param(d * 3.0)


def test_latlong_frames_and_wp_funcs_agree():
    n1, n2 = 12, 5
    f = latlong_frames(n1, n2)
    # rows orthonormal, right x up = dir (right-handed view frame looking along -dir)
    np.testing.assert_allclose(np.einsum("kij,klj->kil", f, f), np.broadcast_to(np.eye(3), f.shape), atol=1e-12)
    np.testing.assert_allclose(np.cross(f[:, 0], f[:, 1]), f[:, 2], atol=1e-12)
    out = wp.empty(n1 * n2, dtype=wp.vec3, device="cpu")
    uv = wp.empty(n1 * n2, dtype=wp.vec2, device="cpu")
    wp.launch(_directions_kernel, dim=(n1, n2), inputs=[n1, n2, out, uv], device="cpu")
    np.testing.assert_allclose(out.numpy(), f[:, 2], atol=2e-6)  # float32 trig
    a, b = np.meshgrid(np.arange(n1), np.arange(n2))
    expect = np.stack([(a.ravel() + 0.5) / n1, (b.ravel() + 0.5) / n2], axis=1)
    np.testing.assert_allclose(uv.numpy(), expect, atol=2e-6)


def test_bounding_sphere_encloses_the_mesh_and_maps_use_it():
    v, t = bumpy_mesh_with_moon()
    c, r = bounding_sphere(v)
    assert np.max(np.linalg.norm(v - c, axis=1)) <= r
    maps = LatLongMapSet.create(v, t, n1=2, n2=2, resolution=8)
    assert np.allclose(maps.center, c) and maps.radius == r


def test_bad_arguments_raise():
    v, t = bumpy_mesh_with_moon()
    with pytest.raises(ValueError, match="resolution"):
        LatLongMapSet.create(v, t, n1=2, n2=2, resolution=0)
    with pytest.raises(ValueError, match="depth_layers"):
        LatLongMapSet.create(v, t, n1=2, n2=2, resolution=8, depth_layers="z2z3")
    with pytest.raises(ValueError, match="far"):
        LatLongMapSet.create(v, t, n1=2, n2=2, resolution=8, far="plane")
    with pytest.raises(ValueError, match="enclose"):
        LatLongMapSet.create(v, t, n1=2, n2=2, resolution=8, center=[0, 0, 0], radius=0.5)
    with pytest.raises(ValueError, match="triangles"):
        LatLongMapSet.create(v, t + 1000, n1=2, n2=2, resolution=8)
    maps = LatLongMapSet.create(v, t, n1=2, n2=2, resolution=8)
    with pytest.raises(ValueError, match="start, stop"):
        maps.render(2, 9)
