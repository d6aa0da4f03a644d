"""The ``csm`` / ``raytrace`` render methods end to end (Ritschel 2007 Sec. 5): config -> CSM -> G-buffer ->
progressive Monte-Carlo passes -> files; analytic and ray-traced references; bad configs and CSM files."""

from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from warpscatter.cli.main import main
from warpscatter.config import load_config
from warpscatter.csm import geometry_digest, load_csm
from warpscatter.csm.occluders import scene_occluders
from warpscatter.errors import ConfigError
from warpscatter.io.images import read_image, write_exr
from warpscatter.pipeline import StageTimer, render
from warpscatter.pipeline import lighting as lighting_module
from warpscatter.pipeline.lighting import pass_seed, render_lighting
from warpscatter.runtime.device import default_device
from warpscatter.scene import build_scene

ROOT = Path(__file__).resolve().parents[1]
GATE = ROOT / "configs" / "csm_gate.yaml"
SMALL = ["camera.width=48", "camera.height=27", "camera.supersample=1", "render.lighting.samples=4",
         "render.lighting.passes=3",
         "render.lighting.csm.maps=[16,8]", "render.lighting.csm.resolution=32"]
AREA = "light={type: area, position: [-3, 8, -2], u: [6, 0, 0], v: [0, 0, 3], radiance: [4, 4, 4]}"


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def sets(*overrides):
    out = []
    for o in overrides:
        out += ["--set", o]
    return out


def test_csm_gate_renders_end_to_end_with_progress_per_pass(tmp_path):
    result = invoke("render", GATE, "-o", tmp_path, "-v", *sets(*SMALL))  # -v: the statistics and every pass
    assert result.exit_code == 0, result.output
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["csm_gate.depth.exr", "csm_gate.exr", "csm_gate.json", "csm_gate.png",
                     "csm_gate.surface.exr"]  # no scattering image: the lighting methods render no in-scattering
    for k in (1, 2, 3):
        assert f"lighting pass {k}/3" in result.output
    assert result.output.count("] write") == 3  # rewritten after passes 1 and 2, then the final image
    assert "csm_kind: latlong" in result.output and "csm_maps: [16, 8]" in result.output
    img = read_image(tmp_path / "csm_gate.exr")
    assert np.isfinite(img).all() and img.mean() > 0.01
    surface = read_image(tmp_path / "csm_gate.surface.exr")
    sky = surface.sum(axis=-1) == 0.0  # no surface: the environment map is the background
    assert 0.1 < sky.mean() < 0.9 and np.all(img[sky].sum(axis=-1) > 0) and np.allclose(img[~sky], surface[~sky])
    # the reference through --method, and an area light with its cube CSM
    for extra, stat in ((["--method", "raytrace"], "method: raytrace"), (sets(AREA), "csm_kind: cube"),
                        (sets(AREA, "render.lighting.csm.local_lights=semi_local"), "csm_kind: latlong")):
        result = invoke("render", GATE, "-o", tmp_path / "b", "-v", "--set", "output.name=b", *sets(*SMALL), *extra)
        assert result.exit_code == 0, result.output
        assert stat in result.output and np.isfinite(read_image(tmp_path / "b" / "b.exr")).all()


def test_progressive_passes_hand_out_images_and_use_new_patterns():
    config = load_config(GATE, [*SMALL, "render.lighting.method=raytrace", "render.lighting.passes=5",
                                "render.lighting.write_every=2"])
    scene = build_scene(config)
    seen = []
    images, stats = render_lighting(scene, config.render.lighting, StageTimer(),
                                    on_pass=lambda im, done, total: seen.append((done, total, im["color"].copy())))
    assert [(d, t) for d, t, _ in seen] == [(2, 5), (4, 5)]
    assert not np.array_equal(seen[0][2], seen[1][2])  # passes 3-4 drew new patterns: the mean moved
    assert stats["passes"] == 5 and np.isfinite(images["color"]).all()
    assert len({pass_seed(s, k) for s in range(3) for k in range(1000)}) == 3000


@pytest.mark.parametrize("overrides, message", [
    (["render.lighting.samples=8"], "render.lighting.samples: must be a perfect square"),
    (["light={type: directional, direction: [0, -1, 0]}"], "render.lighting.method 'csm' lights environment"),
    (["render.lighting.method=null"], "light.type 'environment' needs render.lighting.method"),
    (["render.lighting.csm.file=missing.npz"], "render.lighting.csm.file: file not found"),
    (["light.map=missing.exr"], "light.map: file not found"),
    (["scene.meshes.0.material.brdf.type=blinn"], "scene.meshes.0.material.brdf.type"),
    (["scene.meshes.0.material.brdf={type: lafortune, lobes: []}"], "scene.meshes.0.material.brdf.lobes"),
    (["scene.meshes.0.receiver_only=true"], "every mesh is receiver_only"),
    (["light={type: area, position: [0, 5, 0], u: [1, 0, 0], v: [2, 0, 0]}"], "are parallel"),
    (["light={type: linear, start: [0, 5, 0], end: [0, 5, 0]}"], "start and end must differ"),
    (["render.scattering.method=fourier"], "render.scattering.method 'fourier' is not used by render.lighting"),
    (["render.shadows.method=msm"], "render.shadows.method 'msm' is not used by render.lighting"),
])
def test_bad_lighting_configs_exit_2_and_write_nothing(tmp_path, overrides, message):
    result = invoke("render", GATE, "-o", tmp_path / "o", *sets(*SMALL, *overrides))
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert not (tmp_path / "o").exists()


def test_csm_files_round_trip_and_mismatched_files_are_refused(tmp_path):
    out = tmp_path / "gate.npz"
    result = invoke("precompute", GATE, "-o", out, "--maps", "16x8", "--resolution", "32")
    assert result.exit_code == 0, result.output
    config = load_config(GATE, SMALL)
    scene = build_scene(config)
    csm = load_csm(out)
    assert csm.geometry == geometry_digest(*scene_occluders(scene))
    on_the_fly = render(config, write=False).images["color"]
    from_file = render(load_config(GATE, [*SMALL, f"render.lighting.csm.file={out}"]), write=False).images["color"]
    assert np.array_equal(on_the_fly, from_file)  # the saved CSM is the one the render builds: same image
    # the same lat-long file lights an area light as a semi-local light (Sec. 4.3)
    semi = render(load_config(GATE, [*SMALL, AREA, "render.lighting.csm.local_lights=semi_local",
                                     f"render.lighting.csm.file={out}"]), write=False)
    assert semi.stats["csm_kind"] == "latlong" and semi.images["surface"].max() > 0
    # the cube CSM of an area light: precomputed from the config with the light's samples, the same image again
    cube = tmp_path / "cube.npz"
    result = invoke("precompute", GATE, "-o", cube, "--light-samples", "4x2", "--resolution", "16", "--set", AREA)
    assert result.exit_code == 0 and "cube maps of the area light" in result.output, result.output
    area = [*SMALL, AREA, "render.lighting.csm.light_samples=[4,2]", "render.lighting.csm.resolution=16"]
    assert load_csm(cube).kind == "cube"
    assert np.array_equal(render(load_config(GATE, area), write=False).images["color"],
                          render(load_config(GATE, [*area, f"render.lighting.csm.file={cube}"]), write=False)
                          .images["color"])
    # a CSM of the gate placed elsewhere, one of another kind, a corrupt file: exit 2 before anything is written
    moved = tmp_path / "moved.npz"
    assert invoke("precompute", GATE, "-o", moved, "--maps", "8x4", "--resolution", "16",
                  "--set", "scene.meshes.0.transform.scale=1.1").exit_code == 0
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file")
    for file, extra, message in ((moved, [], "built for other occluders"),
                                 (out, [AREA], "a 'latlong' CSM cannot light the area light"),
                                 (cube, [AREA.replace("[-3, 8, -2]", "[-3, 9, -2]")], "do not lie on this light"),
                                 (bad, [], "not a readable .npz")):
        result = invoke("render", GATE, "-o", tmp_path / "o", *sets(*SMALL, *extra, f"render.lighting.csm.file={file}"))
        assert result.exit_code == 2, result.output
        assert "render.lighting.csm.file:" in result.output and message in result.output
        assert not (tmp_path / "o").exists()


def _plane_config(tmp_path, env_value, extra=()):
    env = tmp_path / "const.exr"
    write_exr(env, np.full((8, 16, 3), env_value, np.float32))
    cfg = tmp_path / "plane.yaml"
    cfg.write_text(f"""
scene:
  meshes:
    - {{procedural: ground_plane, params: {{size: 20}}, material: {{albedo: [0.6, 0.5, 0.4]}}}}
camera: {{position: [0, 3, -4], look_at: [0, 0, 0], width: 40, height: 24, fov_y: 50}}
light: {{type: environment, map: {env}}}
medium: {{sigma_t: 0.0}}
render:
  lighting: {{method: csm, samples: 16, passes: 2, csm: {{maps: [16, 8], resolution: 32}}}}
output: {{dir: out, name: plane, aovs: [color, surface, scattering, depth]}}
""")
    return load_config(cfg, list(extra))


def test_lambertian_plane_under_constant_sky_converges_to_albedo_times_radiance(tmp_path):
    config = _plane_config(tmp_path, 0.7)
    images = render(config, write=False).images
    surf = images["surface"]
    hit = images["depth"] < 90.0
    assert hit.mean() > 0.5
    want = 0.7 * np.array([0.6, 0.5, 0.4])
    assert np.abs(surf[hit].mean(axis=0) / want - 1.0).max() < 0.01  # measured 6.3e-4 (32 strata x 2 passes)
    assert np.abs(surf[hit] - want).max() < 0.12 * want.max()  # measured 0.069 (per-pixel Monte-Carlo noise)
    # the plane is its own occluder in the CSM: bias and normal offset keep it out of its own shadow, so the
    # image is the ray-traced one (same seeds; no shadow ray hits anything) but for a few grazing samples
    ref = render(_plane_config(tmp_path, 0.7, ["render.lighting.method=raytrace"]), write=False).images["surface"]
    assert np.abs(surf - ref).max() < 0.03 * want.max()  # measured 0.004 (0.2 % of the pixel channels differ at all)
    assert np.abs(surf - ref).mean() < 1e-3 * ref.mean()  # measured 7.1e-6
    # a medium attenuates the surface term by exp(-sigma_t s) and adds no in-scattering (documented)
    fog = render(_plane_config(tmp_path, 0.7, ["medium.sigma_t=0.2"]), write=False).images
    assert np.allclose(fog["surface"], surf * np.exp(-0.2 * images["depth"])[..., None], rtol=1e-5, atol=1e-7)
    assert "scattering" not in fog and np.isfinite(fog["color"]).all()


def test_sphere_over_plane_csm_agrees_with_the_raytraced_reference(tmp_path):
    sphere = tmp_path / "sphere.obj"
    trimesh.creation.icosphere(subdivisions=3, radius=0.5).export(sphere)
    cfg = tmp_path / "sphere.yaml"
    cfg.write_text(f"""
scene:
  meshes:
    - {{path: {sphere}, transform: {{translate: [0, 0.8, 0]}}, material: {{albedo: [0.8, 0.8, 0.8]}}}}
    - {{procedural: ground_plane, params: {{size: 8}}, receiver_only: true, material: {{albedo: [0.5, 0.5, 0.5]}}}}
camera: {{position: [0, 2.5, -3.5], look_at: [0, 0.4, 0], width: 48, height: 32, fov_y: 45}}
light: {{type: environment, map: {ROOT / "assets" / "sky_small.exr"}}}
medium: {{sigma_t: 0.0}}
render:
  lighting: {{method: csm, samples: 16, passes: 2, filter: pcf, csm: {{maps: [32, 16], resolution: 64}}}}
""")
    csm = render(load_config(cfg), write=False).images["surface"]
    ref = render(load_config(cfg, ["render.lighting.method=raytrace"]), write=False).images["surface"]
    free = render(load_config(cfg, ["render.lighting.method=raytrace", "scene.meshes.0.receiver_only=true"]),
                  write=False).images["surface"]  # no occluder at all
    # same seeds: the same directions per pixel, so the difference is the CSM's visibility error
    rel = np.abs(csm - ref).mean() / ref.mean()
    assert rel < 0.02  # measured 0.0075 (nearest 0.0079, roulette 0.0094)
    assert abs(csm.mean() / ref.mean() - 1.0) < 0.005  # measured 1.9e-4
    assert np.abs(csm - ref).mean() < 0.35 * np.abs(free - ref).mean()  # measured 0.18 (shadows: 4.2 % of the light)


def test_validate_summarises_the_lighting_configs():
    result = invoke("validate", GATE)
    assert result.exit_code == 0 and "environment map" in result.output and "lighting csm" in result.output
    result = invoke("validate", GATE, "--set", AREA)
    assert result.exit_code == 0 and "area at" in result.output
    result = invoke("validate", GATE, "--set", AREA, "--set", "light.texture=../assets/light_cookie.png")
    assert result.exit_code == 0 and "texture" in result.output and "light_cookie.png" in result.output
    volume = "light={type: volume, position: [0, 5, 0], u: [1, 0, 0], v: [0, 1, 0], w: [0, 0, 1]}"
    result = invoke("validate", GATE, "--set", volume)
    assert result.exit_code == 0 and "volume at [0, 5, 0], edges [1, 0, 0] x [0, 1, 0] x [0, 0, 1]" in result.output


def test_precompute_takes_the_configs_csm_settings_and_their_limits(tmp_path):
    out = tmp_path / "c.npz"
    result = invoke("precompute", GATE, "-o", out, "--set", "render.lighting.csm.maps=[8,4]",
                    "--set", "render.lighting.csm.resolution=16", "--enumeration", "zigzag")
    assert result.exit_code == 0, result.output
    csm = load_csm(out)
    assert (csm.n1, csm.n2, csm.resolution) == (8, 4, 16) and "zigzag" in result.output
    # the options' limits are the settings model's: refused before any work, naming the option
    result = invoke("precompute", GATE, "-o", tmp_path / "d.npz", "--maps", "2000x4")
    assert result.exit_code == 2 and "--maps" in result.output and "1024" in result.output
    assert not (tmp_path / "d.npz").exists()



def test_passes_reuse_one_estimator_setup(monkeypatch):
    """Every pass of a render shades with the one DirectLighting built (checked and uploaded) before the passes: no
    per-pass re-upload of the points, the material table or the CSM. A pass is shade_direct's pass bit for bit,
    splitting it across threads changes nothing, and each pass hands out its own array."""
    from warpscatter.csm import direct_lighting as dl

    built, seeds, csm_uploads = [], [], []
    real_upload = dl.csm_device_data

    class Counting(dl.DirectLighting):
        def __init__(self, *args, **kwargs):
            built.append((args, kwargs))
            super().__init__(*args, **kwargs)

        def shade(self, seed=0):
            seeds.append(seed)
            return super().shade(seed)

    def counting_upload(csm, device=None):
        if str(device) not in csm._device_cache:  # an upload, not a cache hit
            csm_uploads.append(str(device))
        return real_upload(csm, device)

    from warpscatter.csm import occluders

    monkeypatch.setattr(occluders, "_BUILT", type(occluders._BUILT)())  # a fresh CSM (no process-cached upload)
    monkeypatch.setattr(lighting_module, "DirectLighting", Counting)
    monkeypatch.setattr(dl, "csm_device_data", counting_upload)
    monkeypatch.setattr(lighting_module, "csm_device_data", counting_upload)
    config = load_config(GATE, [*SMALL, "render.lighting.passes=3"])
    timer = StageTimer()
    images, stats = render_lighting(build_scene(config), config.render.lighting, timer)
    assert len(built) == 1 and len(seeds) == 3 and stats["passes"] == 3 and "setup" in timer.timings
    assert csm_uploads == [str(default_device())]  # the segment lists went up once, in the csm stage
    args, kwargs = built[0]
    assert kwargs["csm"] is not None and kwargs["filter"] == "roulette"
    one = dl.DirectLighting(*args, **kwargs)
    single = dl.DirectLighting(*args, **{**kwargs, "threads": 1})
    for seed in seeds:
        got = one.shade(seed)
        assert np.array_equal(got, dl.shade_direct(*args, seed=seed, **kwargs))
        assert np.array_equal(got, single.shade(seed))
        got[:] = -1.0  # the caller owns it
        assert np.all(one.shade(seed) >= 0.0)
    assert len(csm_uploads) == 1  # cached on the CSM: none of these set-ups uploaded it again


def test_textured_area_light_csm_agrees_with_raytrace():
    """configs/csm_area.yaml with the stained-glass texture over its area light (light.texture): the cube-CSM render
    and the ray-traced reference, same samples, agree within the CSM's usual distance; the texture is sampled by
    radiance and its mean keeps the light's power (power key)."""
    area = ROOT / "configs" / "csm_area.yaml"
    small = ["camera.width=64", "camera.height=36", "render.lighting.samples=16", "render.lighting.passes=4",
             "light.texture=../assets/light_cookie.png"]
    images = {m: render(load_config(area, [*small, f"render.lighting.method={m}"]), write=False).images["surface"]
              for m in ("csm", "raytrace")}
    plain = render(load_config(area, [*small[:-1], "render.lighting.method=raytrace"]), write=False).images["surface"]
    for img in images.values():
        assert np.isfinite(img).all() and img.min() >= 0.0
    rel = np.abs(images["csm"] - images["raytrace"]).sum() / images["raytrace"].sum()
    assert rel < 0.015  # measured 0.0053
    # the same power through a coloured texture: the texture moves light around, the total stays close
    assert 0.95 < images["raytrace"].sum() / plain.sum() < 1.07  # measured 1.013
    assert np.abs(images["raytrace"] - plain).sum() / plain.sum() > 0.04  # the texture shows (measured 0.088)


def test_volume_light_renders_with_csm_and_raytrace():
    """A volume light (light.type volume, Ritschel 2007's d = 3) over the csm_area scene: csm queries its lat-long
    CSM towards each light point (semi-local, whatever local_lights says) and agrees with the ray-traced reference;
    a coplanar box is refused naming the key."""
    area = ROOT / "configs" / "csm_area.yaml"
    vol = ("light={type: volume, position: [-2, 6, -3], u: [4, 0, 0], v: [0, 1, 0], w: [0, 0, 2], "
           "power: [900, 850, 800]}")
    small = ["camera.width=64", "camera.height=36", "render.lighting.samples=16", "render.lighting.passes=4", vol]
    res = {m: render(load_config(area, [*small, f"render.lighting.method={m}"]), write=False)
           for m in ("csm", "raytrace")}
    assert res["csm"].stats["csm_kind"] == "latlong" and res["csm"].stats["light"] == "volume"
    images = {m: r.images["surface"] for m, r in res.items()}
    assert all(np.isfinite(i).all() and i.min() >= 0.0 for i in images.values()) and images["raytrace"].max() > 0.0
    rel = np.abs(images["csm"] - images["raytrace"]).sum() / images["raytrace"].sum()
    assert rel < 0.025  # measured 0.0088
    with pytest.raises(ConfigError, match="light: u .* coplanar"):
        load_config(area, [vol.replace("w: [0, 0, 2]", "w: [1, 0, 0]")])
