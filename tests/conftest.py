"""Shared test helpers: scenes built directly (no config), small sizes."""

import os

import numpy as np
import pytest

from warpscatter.scene import Scene
from warpscatter.scene.camera import Camera
from warpscatter.scene.lights import DirectionalLight
from warpscatter.scene.medium import Medium


def quad(p0, p1, p2, p3):
    """Two triangles of the quad p0-p1-p2-p3 (float32 vertices, int32 triangles)."""
    v = np.array([p0, p1, p2, p3], dtype=np.float32)
    return v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)


def make_scene(vertices, triangles, camera=None, light=None, medium=None, albedo=(0.5, 0.5, 0.5)):
    camera = camera or Camera(position=[0, 1, 0], look_at=[0, 1, -1], up=[0, 1, 0], fov_y=60, width=48, height=32,
                              near=0.1, far=50)
    light = light or DirectionalLight(direction=[0.3, -1.0, 0.2], irradiance=[1.0, 0.8, 0.6])
    medium = medium or Medium(sigma_t=0.1, albedo=0.9)
    t = np.asarray(triangles, np.int32)
    return Scene(vertices=np.asarray(vertices, np.float32), triangles=t, tri_material=np.zeros(len(t), np.int32),
                 albedo=np.array([albedo], np.float32), opacity=np.ones(1, np.float32), camera=camera, light=light,
                 medium=medium)


@pytest.fixture
def rng():
    return np.random.default_rng(42)


def settings(method: str = "raymarch", **keys):
    """Validated :class:`~warpscatter.scattering.settings.ScatteringSettings` of ``method`` (keys as in configs)."""
    from warpscatter.scattering.settings import ScatteringSettings

    return ScatteringSettings(method=method, **keys)


def render_method(scene, gbuffer, method: str = "raymarch", *, geometry=None, shadow_map=None, **keys):
    """A scattering method's (L_scat as (H, W, 3) numpy, info) through the registry's call shape."""
    from warpscatter import methods
    from warpscatter.pipeline import Frame

    out, info = methods.get("scattering", method).load()(
        Frame(scene, gbuffer, geometry=geometry, shadow_map=shadow_map), settings(method, **keys))
    return out.numpy(), info


def march(scene, gbuffer, *, geometry=None, shadow_map=None, **keys):
    """The ``raymarch`` method's L_scat (H, W, 3) numpy (``visibility`` exact needs ``geometry``)."""
    return render_method(scene, gbuffer, "raymarch", geometry=geometry, shadow_map=shadow_map, **keys)[0]


# ---- hypothesis profiles -------------------------------------------------------------------------
# ``pytest --hypothesis-profile=long tests/test_fuzz.py``: the release-time fuzz run (1000 configs, deterministic; see
# tests/test_fuzz.py). The default profile is hypothesis' own; the fuzz test bounds its count itself.
from hypothesis import HealthCheck  # noqa: E402
from hypothesis import settings as _hypothesis_settings  # noqa: E402

_hypothesis_settings.register_profile(
    "long", max_examples=1000, deadline=None, derandomize=True, database=None, print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


# ---- the CLI's process settings ------------------------------------------------------------------
@pytest.fixture(autouse=True)
def _restore_cli_environment():
    """The CLI sets WARPSCATTER_THREADS / WARPSCATTER_DEVICE for its process (--threads, --device); in-process CLI
    tests must not leave them to later tests (which would then run single-threaded, or with a fixed device)."""
    keys = ("WARPSCATTER_THREADS", "WARPSCATTER_DEVICE")
    saved = {k: os.environ.get(k) for k in keys}
    yield
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
