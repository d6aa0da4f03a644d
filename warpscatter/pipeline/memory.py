"""A render's estimated peak memory, compared with the memory the machine has before any work (docs/guide/
reliability.md).

:func:`estimate_peak_bytes` is an upper bound of a render's peak resident memory: the process itself (Python, Warp,
compiled kernels, the scene), the frame's per-pixel buffers (``camera.width x camera.height x camera.supersample^2``
pixels, bytes per pixel by method), the light's shadow map and the prefiltered methods' rectified, prefix-summed
textures (by ``render.scattering.shadow_map.resolution``), the surface shadows' moment maps and the ``csm`` method's
depth maps. The constants were measured as the peak RSS of CLI renders at two sizes per method (320 x 180 and
1280 x 720, 2 CPU cores): the estimate lies 1.0x to 1.5x above the measured peaks (docs/guide/reliability.md).

:func:`check_memory` refuses a render whose estimate exceeds the memory available to it (``MemAvailable`` of
``/proc/meminfo`` plus what this process already holds, within a cgroup's ``memory.max``), or the budget of the
environment variable ``WARPSCATTER_MEMORY_LIMIT`` (bytes, or with a K, M, G or T suffix, powers of 1024).
"""

from __future__ import annotations

import logging
import os
import re
import resource
import sys
from pathlib import Path

from ..errors import ConfigError

log = logging.getLogger("warpscatter")

#: The environment variable of the memory budget: bytes, or a number with K, M, G or T (powers of 1024).
MEMORY_LIMIT_ENV = "WARPSCATTER_MEMORY_LIMIT"

MIB = 1 << 20
GIB = 1 << 30

#: The process before the frame's buffers: Python, Warp, the compiled kernels, the scene, the image writers (measured
#: 255-275 MiB in CLI renders; a 320 x 180 render from the Python API, files written, peaked at 365-416 MiB).
BASE_BYTES = 384 * MIB
#: Bytes per rendered pixel (after supersampling) at the peak, by method (measured: fourier 175, moments6 129,
#: epipolar 238, raymarch 164, csm 247 per pixel between 320 x 180 and 1280 x 720).
PIXEL_BYTES = {"fourier": 200, "moments4": 200, "moments6": 200, "epipolar": 280, "raymarch": 200,
               "csm": 290, "raytrace": 290}
#: A method this table does not know: the largest.
DEFAULT_PIXEL_BYTES = max(PIXEL_BYTES.values())
#: Bytes per shadow-map texel of every scattering method (the depth map and its look-up copies).
SHADOW_MAP_TEXEL_BYTES = 16
#: Bytes per rectified-map texel of the prefiltered methods besides their filtered texture (depths, depth bounds,
#: weights, prefix sums; measured: fourier at 48 coefficients 224 bytes per texel in all, 192 of them its texture).
RECTIFIED_TEXEL_BYTES = 48
#: The prefiltered methods.
PREFILTERED = ("fourier", "moments4", "moments6")
#: Moments per texel of the moment methods.
MOMENTS = {"moments4": 4, "moments6": 6}
#: Surface shadows with a filterable moment map (``render.shadows.method``): its texels are the shadow map's times
#: ``supersampling^2``; the map, its mip chain and working copies take twice its storage (measured: msm at 64 bits,
#: supersampling 2: 64 bytes per shadow-map texel).
FILTERABLE_SHADOWS = ("msm", "msm_soft", "msm2015", "vsm", "evsm")
SHADOW_MOMENT_COPIES = 2
#: csm built on the fly: bytes per depth-map texel of the maps held at once (measured: 9.5 per texel of an area
#: light's 6 x 32 cube faces between resolution 128 and 256).
CSM_TEXEL_BYTES = 12


def estimate_peak_bytes(config) -> int:
    """An upper bound of the peak resident memory of rendering ``config`` (a validated still config), in bytes."""
    return sum(estimate_terms(config).values())


def estimate_terms(config) -> dict[str, int]:
    """The estimate's terms: ``process``, ``frame`` (per-pixel buffers) and, where used, ``shadow map``,
    ``rectified maps``, ``shadow moments``, ``csm maps``; bytes each."""
    cam = config.camera
    pixels = int(cam.width) * int(cam.height) * int(cam.supersample) ** 2
    lighting = config.render.lighting
    method = lighting.method or config.render.scattering.method
    terms = {"process": BASE_BYTES, "frame": pixels * PIXEL_BYTES.get(method, DEFAULT_PIXEL_BYTES)}
    if lighting.method is not None:
        if lighting.method == "csm" and lighting.csm.file is None:
            csm = lighting.csm
            maps = csm.batch if config.light.type in ("environment",) else max(csm.batch, 6 * _samples(csm))
            terms["csm maps"] = maps * int(csm.resolution) ** 2 * CSM_TEXEL_BYTES
        return terms
    sc = config.render.scattering
    cols, rows = sc.shadow_map.size
    texels = int(cols) * int(rows)
    terms["shadow map"] = texels * SHADOW_MAP_TEXEL_BYTES
    if method in PREFILTERED:
        filtered = sc.filtered_bits_per_texel // 8
        if method != "fourier":  # the moments are prefix-summed as float64 whatever their storage
            filtered = max(filtered, 8 * MOMENTS[method])
        terms["rectified maps"] = texels * (RECTIFIED_TEXEL_BYTES + filtered * (2 if sc.prefiltered.mip_levels > 1
                                                                                else 1))
    shadows = config.render.shadows
    if shadows.method in FILTERABLE_SHADOWS:
        bits = 128 if shadows.method == "msm_soft" else int(shadows.storage)
        layers = 3 if shadows.coloured else 1
        terms["shadow moments"] = texels * int(shadows.supersampling) ** 2 * bits // 8 * layers * SHADOW_MOMENT_COPIES
    return terms


def _samples(csm) -> int:
    """Depth cube maps of an area / linear light's samples (``light_samples`` n1 x n2)."""
    n1, n2 = csm.light_samples
    return int(n1) * int(n2)


def parse_bytes(text: str) -> int:
    """``WARPSCATTER_MEMORY_LIMIT``'s value: bytes, or a number with K, M, G or T (powers of 1024, an optional B).

    Raises:
        ConfigError: not such a number.
    """
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([KMGT]?)(?:I?B)?\s*", text, flags=re.IGNORECASE)
    if not m or float(m.group(1)) <= 0:
        raise ConfigError(f"{MEMORY_LIMIT_ENV}: expected bytes, or a number with K, M, G or T (e.g. 8G), got "
                          f"{text[:40]!r}")
    scale = 1024 ** "KMGT".find(m.group(2).upper()) * 1024 if m.group(2) else 1
    return int(float(m.group(1)) * scale)


def _meminfo_available() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` in bytes, or None where there is none."""
    try:
        text = Path("/proc/meminfo").read_text(encoding="ascii")
    except OSError:
        return None
    m = re.search(r"^MemAvailable:\s+(\d+)\s*kB", text, flags=re.MULTILINE)
    return int(m.group(1)) * 1024 if m else None


def _cgroup_room() -> int | None:
    """What the cgroup (v2) of this process may still allocate (``memory.max`` - ``memory.current``), or None."""
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text(encoding="ascii").strip()
        current = Path("/sys/fs/cgroup/memory.current").read_text(encoding="ascii").strip()
    except OSError:
        return None
    if not limit.isdigit() or not current.isdigit():
        return None  # "max": no limit
    return max(0, int(limit) - int(current))


def _own_rss() -> int:
    """This process's resident memory now (Linux ``/proc/self/statm``; elsewhere its peak so far), in bytes."""
    try:
        return int(Path("/proc/self/statm").read_text(encoding="ascii").split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak if sys.platform == "darwin" else peak * 1024


def memory_budget() -> tuple[int, str] | None:
    """The memory a render may reach, in bytes, and where the figure comes from: ``WARPSCATTER_MEMORY_LIMIT``, or
    the machine's available memory plus what this process holds; None where it cannot be known (not Linux)."""
    text = os.environ.get(MEMORY_LIMIT_ENV, "").strip()
    if text:
        return parse_bytes(text), MEMORY_LIMIT_ENV
    available = _meminfo_available()
    if available is None:
        log.debug("memory check skipped: no MemAvailable in /proc/meminfo on this system (set %s to set a budget)",
                  MEMORY_LIMIT_ENV)
        return None
    room = _cgroup_room()
    source = "MemAvailable"
    if room is not None and room < available:
        available, source = room, "the cgroup's memory.max"
    return available + _own_rss(), f"{source} + this process"


def check_memory(config, budget: tuple[int, str] | None = None) -> int:
    """Refuse a render whose estimated peak memory exceeds the budget (:func:`memory_budget`, or ``budget``).

    Returns:
        The estimate, in bytes.

    Raises:
        ConfigError: the estimate exceeds the budget; names camera.width/height (and supersample), the maps when
            they weigh more than the frame, the estimate and the budget.
    """
    terms = estimate_terms(config)
    estimate = sum(terms.values())
    budget = memory_budget() if budget is None else budget
    if budget is None:
        return estimate
    limit, source = budget
    log.debug("memory: estimated peak %.2f GiB (%s), budget %.2f GiB (%s)", estimate / GIB,
              ", ".join(f"{k} {v / GIB:.2f}" for k, v in terms.items()), limit / GIB, source)
    if estimate <= limit:
        return estimate
    cam = config.camera
    size = f"{cam.width} x {cam.height}" + (f" (supersample {cam.supersample})" if cam.supersample > 1 else "")
    keys = "camera.width/height" + ("/supersample" if cam.supersample > 1 else "")
    maps = {k: v for k, v in terms.items() if k not in ("process", "frame")}
    if sum(maps.values()) > terms["frame"]:
        keys += (", render.lighting.csm.resolution/batch" if "csm maps" in maps else
                 ", render.scattering.shadow_map.resolution")
    override = (f", or raise {MEMORY_LIMIT_ENV}" if source == MEMORY_LIMIT_ENV else
                f", or set {MEMORY_LIMIT_ENV} (e.g. 64G) to allow more at your own risk")
    detail = ", ".join(f"{k} {v / GIB:.1f}" for k, v in terms.items() if v >= 0.05 * GIB)
    raise ConfigError(f"{keys}: a {size} render needs an estimated {estimate / GIB:.1f} GiB at its peak ({detail} "
                      f"GiB), more than the {limit / GIB:.1f} GiB available ({source}); render a smaller image or "
                      f"maps{override}", config.source)


__all__ = ["MEMORY_LIMIT_ENV", "check_memory", "estimate_peak_bytes", "estimate_terms", "memory_budget",
           "parse_bytes"]
