"""``scene.meshes.N.receiver_only``: a mesh that receives shadows but casts none, in every visibility method."""

import numpy as np
import pytest

from warpscatter.bench import bench_scene_config, errors
from warpscatter.config import Config, ConfigError
from warpscatter.csm.occluders import scene_occluders
from warpscatter.pipeline import render_images
from warpscatter.raster.gbuffer import gbuffer_raster
from warpscatter.scene import DeviceGeometry, Scene, build_scene
from warpscatter.scene.camera import Camera
from warpscatter.scene.lights import DirectionalLight
from warpscatter.scene.medium import Medium
from warpscatter.shadows.shadow_map import render_shadow_map


def _two_mesh_scene(receiver_only):
    # mesh 0: a ground quad (4 vertices), mesh 1: a small roof quad above it (4 vertices)
    ground = np.array([[-5, 0, -5], [5, 0, -5], [5, 0, 5], [-5, 0, 5]], np.float32)
    roof = np.array([[-1, 2, -1], [1, 2, -1], [1, 2, 1], [-1, 2, 1]], np.float32)
    quad = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    cam = Camera(position=[0, 1, 6], look_at=[0, 0.5, 0], up=[0, 1, 0], fov_y=60, width=32, height=24, near=0.1,
                 far=30)
    return Scene(vertices=np.concatenate([ground, roof]), triangles=np.concatenate([quad, quad + 4]),
                 tri_material=np.array([0, 0, 1, 1], np.int32), albedo=np.full((2, 3), 0.5, np.float32),
                 opacity=np.ones(2, np.float32), camera=cam, light=DirectionalLight([0.1, -1.0, 0.2], [1, 1, 1]),
                 medium=Medium(sigma_t=0.1, albedo=1.0),
                 receiver_only=None if receiver_only is None else np.array(receiver_only, bool))


def test_casters_keep_only_casting_triangles_compacted():
    scene = _two_mesh_scene([True, False])
    casters = scene.casters()
    assert casters.triangle_count == 2 and len(casters.vertices) == 4
    np.testing.assert_array_equal(casters.vertices[casters.triangles], scene.vertices[scene.triangles[2:]])
    np.testing.assert_array_equal(casters.tri_material, [1, 1])
    assert casters.receiver_only is None
    for every_mesh_casts in (_two_mesh_scene(None), _two_mesh_scene([False, False])):
        assert every_mesh_casts.casters() is every_mesh_casts
    nothing = _two_mesh_scene([True, True]).casters()
    assert nothing.triangle_count == 0 and len(nothing.vertices) == 8  # bounds stay the scene's
    # the CSM occluders are the same triangles (one home for the flag)
    v, t = scene_occluders(scene)
    np.testing.assert_array_equal(v[t], casters.vertices[casters.triangles])
    v2, t2 = scene_occluders(_two_mesh_scene(None), [True, False])
    np.testing.assert_array_equal(v2[t2], v[t])


def test_shadow_map_and_bvh_leave_receivers_out():
    scene = _two_mesh_scene([True, False])
    sm = render_shadow_map(scene, 64)
    full = render_shadow_map(_two_mesh_scene(None), 64)
    # every texel holds the roof or nothing: the ground is not in the map
    assert np.isfinite(sm.depth).any() and np.isinf(sm.depth).any()
    finite = sm.depth[np.isfinite(sm.depth)]
    # the tilted light sees the flat roof over a depth range of +-0.29; the ground lies 2.0 deeper
    assert np.abs(finite - np.median(finite)).max() < 0.5
    # with the ground casting, the map holds ground depths too
    assert np.nanmax(np.where(np.isfinite(full.depth), full.depth, np.nan)) > finite.max() + 1.5
    assert sm.texel_world < 0.5 * full.texel_world  # fitted to the casters (the roof), not the ground
    assert render_shadow_map(_two_mesh_scene([True, True]), 16).depth.min() == np.inf
    geo = DeviceGeometry(scene)
    assert geo.shadow_mesh is not geo.mesh and geo.shadow_mesh.points.shape[0] == 4
    geo_all = DeviceGeometry(_two_mesh_scene(None))
    assert geo_all.shadow_mesh is geo_all.mesh
    with pytest.raises(ValueError, match="receiver_only"):
        _ = DeviceGeometry(_two_mesh_scene([True, True])).shadow_mesh


def _roof_config(roof: str, shadows: str, scattering: dict) -> Config:
    """A ground plane under a small roof, seen from the side; ``roof``: casting, receiver_only or absent."""
    meshes = [{"procedural": "ground_plane", "params": {"size": 40.0}}]
    if roof != "absent":
        meshes.append({"procedural": "ground_plane", "params": {"size": 3.0}, "transform": {"translate": [0, 2, 0]},
                       "receiver_only": roof == "receiver_only"})
    return Config.from_dict({
        "scene": {"meshes": meshes},
        "camera": {"position": [0.0, 1.0, 6.0], "look_at": [0.0, 0.4, 0.0], "fov_y": 55, "width": 64, "height": 48,
                   "near": 0.1, "far": 60.0},
        "light": {"type": "directional", "direction": [0.15, -1.0, 0.1], "irradiance": [2.0, 2.0, 2.0]},
        "medium": {"sigma_t": 0.1, "albedo": 1.0},
        "render": {"scattering": {**scattering, "shadow_map": {"resolution": 256}},
                   "shadows": {"method": shadows}}})


@pytest.mark.parametrize("shadows,scattering", [
    ("pcf", {"method": "raymarch", "visibility": "exact", "steps": 16}),
    ("msm", {"method": "raymarch", "visibility": "shadow_map", "steps": 16}),
    ("msm_soft", {"method": "fourier"}),
    ("pcss", {"method": "moments6"}),
])
def test_receiver_only_occluder_casts_no_shadow(shadows, scattering):
    images = {}
    for roof in ("casting", "receiver_only", "absent"):
        cfg = _roof_config(roof, shadows, scattering)
        scene = build_scene(cfg)
        imgs, _ = render_images(scene, cfg.render)
        gbuf = DeviceGeometry(scene)
        images[roof] = imgs, gbuffer_raster(scene, gbuf).material.numpy()  # 0: the ground
    # pixels that see the ground in both scenes: their whole view ray is the same
    ground = (images["receiver_only"][1] == 0) & (images["absent"][1] == 0)
    assert ground.mean() > 0.3
    for key in ("surface", "scattering"):
        with_roof, without = images["receiver_only"][0][key][ground], images["absent"][0][key][ground]
        np.testing.assert_allclose(with_roof, without, rtol=1e-5, atol=1e-6)  # measured: bitwise equal
    # the casting roof does shadow the ground under it and the rays below it (the test could fail)
    dark = images["casting"][0]["surface"][ground].mean(-1) < 0.5 * images["absent"][0]["surface"][ground].mean(-1)
    assert dark.mean() > 0.03  # measured 0.060 of the ground pixels
    scat_cast, scat_free = images["casting"][0]["scattering"][ground], images["absent"][0]["scattering"][ground]
    assert np.abs(scat_cast - scat_free).mean() > 0.02 * scat_free.mean()  # measured 0.042-0.045


def test_all_receivers_refused():
    data = _roof_config("receiver_only", "pcf", {"method": "raymarch"}).model_dump(mode="json")
    data["scene"]["meshes"][0]["receiver_only"] = True
    with pytest.raises(ConfigError, match=r"scene\.meshes: every mesh is receiver_only"):
        Config.from_dict(data)


def test_receiver_only_ground_removes_the_moment_receiver_error_on_the_canopy():
    # the meadow shadows nothing visible: the exact image does not change (same seed, bitwise), but in the
    # rectified map every ray ending on the ground sees the ground's own depths just behind its fragment depth,
    # where six moments leave the widest bounds (moments6 under-estimates the lower image). Caster culling (on by
    # default for the moment methods, tests/test_caster_culling.py) removes most of it too; off here, and so is
    # skip_unseen_planes, which would leave the meadow out of the maps in both arms (tests/test_unseen_planes.py)
    w, h, no_surf = 160, 90, {"enabled": False}
    exact = {"method": "raymarch", "visibility": "exact", "steps": 128}
    res = {}
    for ro in (False, True):
        for label, sc in (("exact", exact), ("fourier", {"method": "fourier"}),
                          ("moments6", {"method": "moments6", "moments": {"storage_bits": 192}})):
            cfg = bench_scene_config("canopy", w, h, receiver_only_ground=ro, surfaces=no_surf,
                                     scattering={**sc, "shadow_map": {"resolution": 256,
                                                                      "skip_unseen_planes": False},
                                                 "prefiltered": {"caster_culling": False}})
            res[label, ro] = render_images(build_scene(cfg), cfg.render)[0]["scattering"]
    np.testing.assert_array_equal(res["exact", False], res["exact", True])
    err = {k: errors(v, res["exact", k[1]])["rel_l1"] for k, v in res.items() if k[0] != "exact"}
    # measured (256^2 map, no culling): moments6 0.0590 -> 0.0277, fourier 0.0356 -> 0.0293
    assert err["moments6", True] < 0.7 * err["moments6", False]
    assert err["moments6", True] < 0.035 and err["fourier", True] < 0.035
