"""The examples' promises beyond running (tests/test_doc_examples.py runs every block): the kernel example's shadow
values, the Marcher example against the library's own marcher, the Python API examples' results, the set-up
commands. Each test finds its block in the README or the docs by a string it contains (doc_examples.find_block),
so the text may move between pages."""

import re
from pathlib import Path

import doc_examples as de
import numpy as np
import warp as wp

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def test_kernel_example_gives_the_shadows_it_states(tmp_path, monkeypatch):
    from warpscatter.shadows import moments

    for block, ns in de.run_examples("def my_shadows", tmp_path, monkeypatch):
        z = np.array([-0.5, 0.2], np.float32)
        b = moments.moments4(np.array([0.0, 0.0], np.float32))  # an occluder at depth 0 on both texels
        out = wp.zeros(2, dtype=float)
        wp.launch(ns["my_shadows"], dim=2, inputs=[wp.array(b, dtype=wp.vec4), wp.array(z, dtype=float), out])
        s = out.numpy()
        assert s[0] < 0.05 and s[1] > 0.9, block.where  # in front of the occluder lit, behind it shadowed
        if "shadow" in ns:  # the example's own launch says the same
            np.testing.assert_array_equal(ns["shadow"].numpy(), s, err_msg=block.where)


def test_marcher_example_matches_the_library_marcher(tmp_path, monkeypatch):
    # the user kernel marches with the library's estimator: every camera pixel's ray, with ray k the random stream
    # of pixel k, against the method's marcher (the directions differ by float rounding only)
    from warpscatter.raster.gbuffer import gbuffer_raster
    from warpscatter.scattering.raymarch import march_pixels
    from warpscatter.scene import DeviceGeometry

    for block, ns in de.run_examples("def my_rays", tmp_path, monkeypatch):
        scene, m = ns["scene"], ns["m"]
        cam = scene.camera
        assert max(cam.width, cam.height) <= de.MAX_SIDE  # shrunk by the harness
        gbuffer = ns.get("gbuffer") or gbuffer_raster(scene, DeviceGeometry(scene))
        ref = march_pixels(cam, gbuffer.distance, m).numpy().reshape(-1, 3)
        n = cam.width * cam.height
        out = wp.zeros(n, dtype=wp.vec3)
        wp.launch(ns["my_rays"], n, [m, wp.array(np.tile(cam.position.astype(np.float32), (n, 1)), dtype=wp.vec3),
                                     wp.array(cam.ray_directions().reshape(-1, 3).astype(np.float32), dtype=wp.vec3),
                                     wp.array(gbuffer.distance.numpy().ravel(), dtype=float), out])
        err = np.abs(out.numpy() - ref).sum() / ref.sum()
        assert err < 1e-5 and ref.sum() > 0.0, (block.where, err)  # measured 1.6e-7


def test_render_example_returns_what_it_states(tmp_path, monkeypatch):
    for block, ns in de.run_examples('result.images["color"]', tmp_path, monkeypatch):
        result = ns["result"]
        h, w = result.config.camera.height, result.config.camera.width
        assert result.images["color"].shape == (h, w, 3) and result.timings and result.stats["method"], block.where


def test_method_call_shape_example_runs(tmp_path, monkeypatch):
    for block, ns in de.run_examples('methods.get("scattering"', tmp_path, monkeypatch):
        assert np.isfinite(ns["l_scat"].numpy()).all() and ns["info"]["epipolar_raymarched_fraction"] > 0, block.where


def test_readme_setup_commands():
    # the two set-up commands (skipped by the doc-example runner; .ci/run installs the same way)
    text = re.sub(r"\s+", " ", README)
    assert re.search(r"pip install -e \. && \.venv/bin/warpscatter render configs/quickstart\.yaml", text)
    assert 'pip install -e ".[test]" && .venv/bin/pytest' in text
