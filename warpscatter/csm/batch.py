"""Host batch queries of coherent shadow maps (Ritschel 2007 Sec. 4): many (point, direction) or (point, light
parameters) pairs launched as :func:`~warpscatter.csm.query.visibility_kernel`; ``bias`` in object-space units.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..runtime import parallel
from ..runtime.device import default_device
from .compress import KIND_CUBE, KIND_LATLONG, CoherentShadowMap
from .query import FILTERS, CSMData, CSMObjects, csm_device_data, visibility_kernel


def _vec3_rows(a, name: str, n: int | None = None) -> np.ndarray:
    try:
        v = np.asarray(a, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric (K, 3) array") from exc
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{name} must have shape (K, 3), got {v.shape}")
    if n is not None and v.shape[0] != n:
        raise ValueError(f"{name} must have {n} rows like points, got {v.shape[0]}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} contains non-finite values")
    return np.ascontiguousarray(v)


def _directions(directions, n: int) -> np.ndarray:
    d = _vec3_rows(directions, "directions", n)
    if np.any(np.all(d == 0.0, axis=1)):
        raise ValueError("directions must be non-zero")
    return d


def _check_bias(bias) -> None:
    if not np.isfinite(bias) or bias < 0.0:
        raise ValueError(f"bias must be a finite number >= 0, got {bias!r}")


def _expect_kind(csm, kind: str, name: str) -> None:
    if not isinstance(csm, CoherentShadowMap):
        raise ValueError(f"{name} must be a CoherentShadowMap, got {type(csm).__name__}")
    if csm.kind != kind:
        raise ValueError(f"{name} must be a {kind!r} CSM, got kind {csm.kind!r}")


def _filter_mode(filter: str) -> int:
    if filter not in FILTERS:
        raise ValueError(f"filter must be one of {tuple(FILTERS)}, got {filter!r}")
    return FILTERS[filter]


def _run_query(csm, points, queries, dtype, bias, mode, seed, device, threads) -> np.ndarray:
    """Launch :func:`visibility_kernel` over K checked queries (of Warp type ``dtype``) against the CSM struct ``csm``;
    (K,) float32."""
    out = wp.empty(points.shape[0], dtype=wp.float32, device=device)
    parallel.launch_rows(
        visibility_kernel, points.shape[0],
        [csm, wp.array(points, dtype=wp.vec3, device=device), wp.array(queries, dtype=dtype, device=device),
         float(bias), mode, int(seed), out],
        device, threads=threads, min_chunk=1024,
    )
    return out.numpy()


def csm_visibility_batch(
    csm: CoherentShadowMap,
    points,
    directions,
    *,
    filter: str = "nearest",
    bias: float = 0.0,
    seed: int = 0,
    device: str | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Visibility of many (point, direction) pairs against one CSM: (K,) float32 in [0, 1] (1 = lit).

    Args:
        csm: the coherent shadow map (object space = the space of the points).
        points: (K, 3) query points.
        directions: (K, 3) directions towards the light (any non-zero length).
        filter: ``"nearest"``, ``"pcf"`` or ``"roulette"``.
        bias: depth bias in scene units (>= 0).
        seed: random seed of the roulette filter.
        device, threads: Warp device and CPU worker threads.

    Raises:
        ValueError: malformed points/directions, zero directions, unknown filter, negative or non-finite bias.
    """
    device = default_device(device)
    mode = _filter_mode(filter)
    p = _vec3_rows(points, "points")
    d = _directions(directions, p.shape[0])
    _check_bias(bias)
    _expect_kind(csm, KIND_LATLONG, "csm")
    return _run_query(csm_device_data(csm, device), p, d, wp.vec3, bias=bias, mode=mode,
                      seed=seed, device=device, threads=threads)


#: Smallest ratio of a rigid object's smallest to largest singular value (float32 T^-1 holds ~1e-7 precision).
MAX_OBJECT_CONDITION_INVERSE = 1.0e-6


def object_arrays(objects, device) -> tuple[wp.array, wp.array]:
    """Device arrays of rigid objects (Sec. 4.6), ``(csm, transform)`` pairs of a lat-long CSM and its 4x4 object ->
    world matrix (None: identity): the CSMs and the world -> object matrices T^-1.

    Raises:
        ValueError: a transform that is not a finite, invertible affine 4x4 matrix, or a cube CSM.
    """
    datas, invs = [], []
    for k, (csm, transform) in enumerate(objects):
        t = np.eye(4) if transform is None else np.asarray(transform, dtype=np.float64)
        if t.shape != (4, 4) or not np.all(np.isfinite(t)) or not np.allclose(t[3], [0, 0, 0, 1]):
            raise ValueError(f"objects[{k}] transform must be a finite affine 4x4 matrix")
        sv = np.linalg.svd(t[:3, :3], compute_uv=False)
        if not sv[-1] > MAX_OBJECT_CONDITION_INVERSE * sv[0]:  # relative: a uniform scale of any size inverts exactly
            raise ValueError(f"objects[{k}] transform is singular or nearly so (its linear part's singular values "
                             f"{sv[0]:.3g} ... {sv[-1]:.3g}: a float32 inverse would lose the object's shape)")
        _expect_kind(csm, KIND_LATLONG, f"objects[{k}] csm")
        datas.append(csm_device_data(csm, device))
        invs.append(np.linalg.inv(t).astype(np.float32))
    return (wp.array(datas, dtype=CSMData, device=device),
            wp.array(np.stack(invs), dtype=wp.mat44, device=device))


def csm_objects_visibility_batch(
    objects,
    points,
    directions,
    *,
    filter: str = "nearest",
    bias: float = 0.0,
    seed: int = 0,
    device: str | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Visibility of (point, direction) pairs against several rigid objects, each with its CSM and placement: (K,)
    float32 product of the objects' visibilities.

    Args:
        objects: sequence of ``(csm, transform)``: CSM and 4x4 object -> world matrix (None = identity).
        points, directions, filter, bias, seed, device, threads: as in :func:`csm_visibility_batch` (world space).

    Raises:
        ValueError: as :func:`csm_visibility_batch`, plus an empty object list or a singular / non-affine T.
    """
    device = default_device(device)
    mode = _filter_mode(filter)
    objects = list(objects)
    if not objects:
        raise ValueError("objects must hold at least one (csm, transform) pair")
    p = _vec3_rows(points, "points")
    d = _directions(directions, p.shape[0])
    _check_bias(bias)
    data = CSMObjects()
    data.csms, data.inv_transforms = object_arrays(objects, device)
    return _run_query(data, p, d, wp.vec3, bias=bias, mode=mode, seed=seed,
                      device=device, threads=threads)


def csm_local_visibility_batch(
    csm: CoherentShadowMap,
    points,
    light_params,
    *,
    filter: str = "nearest",
    bias: float = 0.0,
    seed: int = 0,
    device: str | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """Visibility (K,) float32 in [0, 1] between points and light points of a fixed local light (a ``"cube"`` CSM).

    Args:
        csm: cube CSM from :func:`~warpscatter.csm.compress.build_cube_csm`.
        points: (K, 3) query points.
        light_params: (K, 2) light parameters x in [0, 1]^2 (second one ignored for linear lights, n2 = 1).
        filter, bias, seed, device, threads: as in :func:`csm_visibility_batch`.

    Raises:
        ValueError: a non-cube CSM, malformed inputs, light parameters outside [0, 1], unknown filter, bad bias.
    """
    device = default_device(device)
    mode = _filter_mode(filter)
    _expect_kind(csm, KIND_CUBE, "csm")
    p = _vec3_rows(points, "points")
    x = np.asarray(light_params, dtype=np.float32)
    if x.shape != (p.shape[0], 2):
        raise ValueError(f"light_params must have shape ({p.shape[0]}, 2), got {x.shape}")
    if not np.all((x >= 0.0) & (x <= 1.0)):
        raise ValueError("light_params must lie in [0, 1]")
    _check_bias(bias)
    return _run_query(csm_device_data(csm, device), p, np.ascontiguousarray(x), wp.vec2,
                      bias=bias, mode=mode, seed=seed, device=device, threads=threads)
