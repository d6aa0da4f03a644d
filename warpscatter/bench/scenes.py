"""The bench scenes: the bundled configs (``configs/NAME.yaml``) at bench sizes, and the timed render of one case."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import yaml

from .. import methods
from ..io.resources import bundled_asset, bundled_config
from ..pipeline import StageTimer, compile_kernels, render_images
from ..scene import build_scene
from .report import errors, stage_medians

#: Bench scene name -> the bundled config it loads (``colonnade_spot``: the colonnade under a textured spot light).
SCENES = {"colonnade": "colonnade", "canopy": "canopy", "window": "window", "colonnade_spot": "colonnade",
          "quickstart": "quickstart", "terrain": "terrain", "gate": "gate", "gate_translucent": "gate_soft_shadows",
          "spot_fence": "spot"}
#: The textured spot above the colonnade, outside the view (the ``epipolar`` suite's light).
COLONNADE_SPOT = {"type": "spot", "position": [10.0, 25.0, 14.0], "direction": [-10.0, -22.5, -14.0],
                  "cone_deg": 25.0, "intensity": [2400.0, 2250.0, 2100.0]}


def bench_light_texture() -> Path:
    """The bundled light cookie (source checkout), else a generated 128^2 window-pane texture in a temp folder."""
    try:
        return bundled_asset("light_cookie.png")
    except FileNotFoundError:
        pass
    import tempfile

    from ..io.images import write_png

    path = Path(tempfile.gettempdir()) / "warpscatter-bench-cookie.png"
    if not path.is_file():
        y, x = np.mgrid[0:128, 0:128] / 128.0
        panes = ((np.abs((x * 4) % 1 - 0.5) < 0.42) & (np.abs((y * 4) % 1 - 0.5) < 0.42)).astype(np.float32)
        tint = np.stack([0.6 + 0.4 * x, 0.7 + 0.3 * y, 1.0 - 0.5 * x], -1).astype(np.float32)
        write_png(path, panes[..., None] * tint)
    return path


def bench_scene_config(name: str, width: int, height: int, leaves: int | None = None,
                       receiver_only_ground: bool = False, mirror_light: bool = False, medium: dict | None = None,
                       turn_light_deg: float = 0.0, **render):
    """A validated config of a bench scene: the bundled config at ``width`` x ``height`` with the bench's ``render``.

    Args:
        name: a key of :data:`SCENES`.
        width, height: image size in pixels.
        leaves: leaf quads of the canopy (None: the config's).
        receiver_only_ground: mark the ground plane ``receiver_only`` (the exact image is unchanged).
        mirror_light: negate x and z of a directional light's direction (the other epipole comes into view).
        turn_light_deg: turn a directional light this many degrees about +y (90: both epipoles far outside).
        medium: keys of the ``medium`` section to change (e.g. ``{"sigma_t": 0.3}``).
        **render: the config's ``render`` section (replaces the file's).

    Raises:
        FileNotFoundError: the bundled configs are not installed (see :mod:`..io.resources`).
    """
    from ..config import Config

    path = bundled_config(SCENES[name])
    data = yaml.safe_load(path.read_text(encoding="utf-8"))
    meshes = data["scene"]["meshes"]
    for mesh in meshes:
        if leaves is not None and mesh.get("procedural") == "canopy":
            mesh["params"] = {**mesh.get("params", {}), "leaves": int(leaves)}
        if receiver_only_ground and mesh.get("procedural") == "ground_plane":
            mesh["receiver_only"] = True
    if name == "colonnade_spot":
        data["light"] = {**COLONNADE_SPOT, "texture": str(bench_light_texture())}
    if mirror_light:
        if data["light"].get("type") != "directional":
            raise ValueError(f"mirror_light: {name} has no directional light")
        x, y, z = data["light"]["direction"]
        data["light"] = {**data["light"], "direction": [-x, y, -z]}
    if turn_light_deg:
        if data["light"].get("type") != "directional":
            raise ValueError(f"turn_light_deg: {name} has no directional light")
        x, y, z = data["light"]["direction"]
        c, s = np.cos(np.radians(turn_light_deg)), np.sin(np.radians(turn_light_deg))
        data["light"] = {**data["light"], "direction": [float(c * x + s * z), y, float(c * z - s * x)]}
    if medium:
        data["medium"] = {**data.get("medium", {}), **medium}
    data["camera"] = {**data["camera"], "width": width, "height": height}
    data["render"] = render
    data.pop("output", None)
    return Config.from_dict(data, config_dir=path.parent)


def _dense_mesh(min_triangles: int):
    """A height-field terrain with at least ``min_triangles`` triangles (from the procedural generators)."""
    from ..scene.procedural import terrain

    res = int(np.ceil(np.sqrt(min_triangles / 2.0))) + 1
    mesh = terrain(size=40.0, resolution=res, amplitude=3.0, seed=1)
    return mesh.vertices, mesh.triangles


def _bumpy_sphere(count: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed, bumpy UV sphere (2 count^2 - ... triangles; count 246: about 240k) for the CSM suite."""
    import trimesh

    m = trimesh.creation.uv_sphere(radius=1.0, count=[count, count])
    n = np.asarray(m.vertices, np.float64)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rng = np.random.default_rng(0)
    k, ph = rng.normal(size=(24, 3)) * 3.0, rng.uniform(0.0, 2.0 * np.pi, 24)
    r = 1.0 + 0.5 * np.mean(np.sin(n @ k.T + ph), axis=1)
    return (n * r[:, None]).astype(np.float32), np.asarray(m.faces, np.int32)


def render_timed(cfg, repeats, warmup, device=None):
    """Render a config's classic stages ``warmup + repeats`` times; returns (per-stage medians ms, last images,
    compile s, scene, stats)."""
    t0 = time.perf_counter()
    method = methods.get("scattering", cfg.render.scattering.method)
    compile_kernels(methods.CLASSIC_MODULES + method.modules, device)
    compile_s = time.perf_counter() - t0
    scene = build_scene(cfg)
    runs, images = [], None
    for k in range(warmup + max(1, repeats)):
        timer = StageTimer()
        images, stats = render_images(scene, cfg.render, timer=timer, device=device)
        if k >= warmup:
            runs.append(timer.timings)
    return median_stages(runs), images, compile_s, scene, stats


def median_stages(runs: list[dict], names=None) -> dict:
    """Per-stage median (ms) over the timings of several runs (``names``: those stages only; compile excluded)."""
    return stage_medians(runs, names)  # the same medians; every repeat is recorded for the report


def scattering_rows(report, name, cfg_kw, params, repeats, warmup, reference=None, extra=None):
    """Time one configuration's scattering stages and add a row with errors against ``reference``; returns
    (row, images, stats)."""
    cfg = bench_scene_config(**cfg_kw)
    stages, images, compile_s, scene, stats = render_timed(cfg, repeats, warmup)
    technique = {k: v for k, v in stages.items() if k not in ("upload", "bvh", "gbuffer", "shadow_map", "shading")}
    marched = stats.get("epipole_raymarched_fraction")
    row = report.add(name=name, params=params, median_ms=sum(technique.values()), stages_ms=technique,
                     extra={"compile_s": round(compile_s, 2), **(extra or {}),
                            **({"epipole_pct": round(100 * marched, 2)} if marched is not None else {})})
    if reference is not None:
        row.update(errors(images["scattering"], reference))
    return row, images, stats


__all__ = ["COLONNADE_SPOT", "SCENES", "bench_light_texture", "bench_scene_config", "median_stages", "render_timed",
           "scattering_rows"]
