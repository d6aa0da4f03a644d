"""BRDFs of the CSM renderer (Ritschel 2007 Sec. 5.1): Lafortune lobes, their importance sampling (pdf integral,
chi-square), reciprocity, energy and the reduction to Phong / Lambert."""

import numpy as np
import pytest
import scipy.stats
import warp as wp

from warpscatter.csm.brdf import (
    MaterialData,
    MaterialTable,
    brdf_eval,
    brdf_pdf,
    cos_power_pdf,
    cos_power_sample,
    lafortune_axis,
    lafortune_lobe,
    lafortune_lobe_weight,
    lambert_pdf,
    lambert_sample,
    luminance,
    material_eval,
    material_pdf,
    material_sample,
    orthonormal_basis,
    shading_eval,
    shading_pdf,
    shading_point,
    shading_sample,
)

N = np.array([0.0, 0.0, 1.0])


@wp.kernel
def _eval_kernel(mat: MaterialData, m: int, n: wp.vec3, wo: wp.array(dtype=wp.vec3), wi: wp.array(dtype=wp.vec3),
                 f: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=wp.float32)):
    k = wp.tid()
    f[k] = material_eval(mat, m, n, wo[k], wi[k])
    pdf[k] = material_pdf(mat, m, n, wo[k], wi[k])


@wp.kernel
def _phong_kernel(n: wp.vec3, kd: wp.vec3, ks: wp.vec3, e: float, wo: wp.array(dtype=wp.vec3),
                  wi: wp.array(dtype=wp.vec3), f: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=wp.float32)):
    k = wp.tid()
    f[k] = brdf_eval(n, wo[k], wi[k], kd, ks, e)
    pdf[k] = brdf_pdf(n, wo[k], wi[k], kd, ks, e)


@wp.kernel
def _sample_kernel(mat: MaterialData, m: int, n: wp.vec3, wo: wp.vec3, seed: int, out: wp.array(dtype=wp.vec3)):
    k = wp.tid()
    rng = wp.rand_init(seed, k)
    xi = wp.vec2(wp.randf(rng), wp.randf(rng))
    out[k] = material_sample(mat, m, n, wo, xi, wp.randf(rng))


def _eval(table, m, wo, wi):
    wo = np.ascontiguousarray(np.broadcast_to(wo, wi.shape), np.float32)
    f = wp.empty(len(wi), dtype=wp.vec3)
    p = wp.empty(len(wi), dtype=wp.float32)
    wp.launch(_eval_kernel, dim=len(wi), inputs=[table.device_data(), m, wp.vec3(*N), wp.array(wo, dtype=wp.vec3),
                                                 wp.array(wi.astype(np.float32), dtype=wp.vec3), f, p])
    return f.numpy().astype(np.float64), p.numpy().astype(np.float64)


def _sphere_grid(n_theta=400, n_phi=800):
    """Midpoint grid over the sphere: directions and their solid angles (sum 4 pi)."""
    ct = -1.0 + 2.0 * (np.arange(n_theta) + 0.5) / n_theta
    ph = 2.0 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    c, p = np.meshgrid(ct, ph, indexing="ij")
    s = np.sqrt(1.0 - c * c)
    d = np.stack([s * np.cos(p), s * np.sin(p), c], -1).reshape(-1, 3)
    return d, np.full(len(d), 4.0 * np.pi / d.shape[0])


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


# two lobes: a forward glossy lobe (Phong-like, slightly off-specular) and a retro-reflective one
LAF = {"albedo": (0.3, 0.25, 0.2), "lafortune": [
    {"coefficients": (-0.9, -0.9, 1.0), "exponent": 12.0, "color": (0.6, 0.6, 0.6)},
    {"coefficients": (0.7, 0.7, 0.7), "exponent": 5.0, "color": (0.3, 0.4, 0.5)}]}


@pytest.fixture(scope="module")
def table():
    return MaterialTable.from_specs([LAF, {"albedo": (0.5, 0.5, 0.5)}])


@pytest.mark.parametrize("wo", [(0.0, 0.0, 1.0), (0.6, 0.0, 0.8), (0.3, -0.9, 0.3)])
def test_lafortune_sampling_pdf_integrates_to_one(table, wo):
    d, dw = _sphere_grid()
    _, pdf = _eval(table, 0, _unit(wo), d)
    assert abs((pdf * dw).sum() - 1.0) < 2e-3  # measured 2.6e-7 .. 7.8e-5 (midpoint rule, cos^12 peak)
    _, pdf_l = _eval(table, 1, _unit(wo), d)
    assert abs((pdf_l * dw).sum() - 1.0) < 1e-4  # Lambert alone: measured 3.2e-8


def test_lafortune_sampler_chi_square(table):
    wo = _unit((0.6, 0.0, 0.8))
    n = 200_000
    out = wp.empty(n, dtype=wp.vec3)
    wp.launch(_sample_kernel, dim=n, inputs=[table.device_data(), 0, wp.vec3(*N), wp.vec3(*wo), 11, out])
    s = out.numpy().astype(np.float64)
    assert np.allclose(np.linalg.norm(s, axis=1), 1.0, atol=1e-5)
    # equal-area bins in (cos theta, phi); expected counts from the pdf integrated on a finer grid
    nt, nph, sub = 20, 24, 8
    ti = np.clip(((s[:, 2] + 1.0) / 2.0 * nt).astype(int), 0, nt - 1)
    pi = np.clip((np.mod(np.arctan2(s[:, 1], s[:, 0]), 2 * np.pi) / (2 * np.pi) * nph).astype(int), 0, nph - 1)
    counts = np.bincount(ti * nph + pi, minlength=nt * nph).astype(np.float64)
    d, dw = _sphere_grid(nt * sub, nph * sub)
    _, pdf = _eval(table, 0, wo, d)
    expected = (pdf * dw).reshape(nt, sub, nph, sub).sum(axis=(1, 3)).ravel() * n
    keep = expected > 5.0
    assert counts[~keep].sum() < 1e-3 * n  # measured 48 of 200k samples in the low-probability bins
    chi2 = ((counts[keep] - expected[keep]) ** 2 / expected[keep]).sum()
    p = scipy.stats.chi2.sf(chi2, keep.sum() - 1)
    assert p > 1e-3  # measured p = 0.49 (chi2 = 249 on 249 dof)


def test_lafortune_is_reciprocal_and_conserves_energy_when_normalized(table):
    rng = np.random.default_rng(5)
    a = rng.normal(size=(2000, 3))
    b = rng.normal(size=(2000, 3))
    a[:, 2] = np.abs(a[:, 2])
    b[:, 2] = np.abs(b[:, 2])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    f_ab = np.stack([_eval(table, 0, a[k], b[k:k + 1])[0][0] for k in range(0, 2000, 97)])
    f_ba = np.stack([_eval(table, 0, b[k], a[k:k + 1])[0][0] for k in range(0, 2000, 97)])
    assert np.allclose(f_ab, f_ba, rtol=1e-5, atol=1e-7)  # measured 2.2e-8 abs, 2.2e-7 rel (float32 rounding)
    # a normalized-Phong-equivalent Lafortune lobe with lum(kd) + lum(ks) = 0.9 reflects at most 0.9 of the light
    e = 20.0
    rho = 0.4 * (e + 2.0) / (2.0 * np.pi)
    t2 = MaterialTable.from_specs([{"albedo": (0.5, 0.5, 0.5), "lafortune": [
        {"coefficients": (-1.0, -1.0, 1.0), "exponent": e, "color": (rho, rho, rho)}]}])
    d, dw = _sphere_grid(800, 800)
    for wo in [(0, 0, 1), (0.7, 0, 0.714), (0.95, 0, 0.312)]:
        f, _ = _eval(t2, 0, _unit(wo), d)
        albedo = (f[:, 0] * np.maximum(d[:, 2], 0.0) * dw).sum()
        assert albedo <= 0.9 + 2e-3  # measured 0.8999 at normal incidence, 0.786 / 0.628 towards grazing
        # the estimator E[f cos / pdf] with the importance sampler reproduces the quadrature (moment check)
        n = 100_000
        out = wp.empty(n, dtype=wp.vec3)
        wp.launch(_sample_kernel, dim=n, inputs=[t2.device_data(), 0, wp.vec3(*N), wp.vec3(*_unit(wo)), 3, out])
        s = out.numpy().astype(np.float64)
        fs, ps = _eval(t2, 0, _unit(wo), s)
        w = np.where(ps > 0, fs[:, 0] * np.maximum(s[:, 2], 0.0) / np.maximum(ps, 1e-30), 0.0)
        assert abs(w.mean() - albedo) < 4.0 * w.std() / np.sqrt(n) + 1e-4  # measured 1.24, 0.20, 0.05 sigma


def test_lafortune_reduces_to_phong_and_lambert():
    rng = np.random.default_rng(2)
    wi = rng.normal(size=(3000, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    kd, ks, e = (0.4, 0.3, 0.2), (0.3, 0.3, 0.3), 17.0
    rho = [k * (e + 2.0) / (2.0 * np.pi) for k in ks]
    laf = MaterialTable.from_specs([{"albedo": kd, "lafortune": [
        {"coefficients": (-1.0, -1.0, 1.0), "exponent": e, "color": rho}]}])
    phong = MaterialTable.phong(np.float32([kd]), np.float32([ks]), e)
    for wo in [_unit((0.2, 0.1, 0.9)), _unit((-0.8, 0.3, 0.2))]:
        f_l, p_l = _eval(laf, 0, wo, wi)
        f_t, p_t = _eval(phong, 0, wo, wi)
        f = wp.empty(len(wi), dtype=wp.vec3)
        p = wp.empty(len(wi), dtype=wp.float32)
        wp.launch(_phong_kernel, dim=len(wi), inputs=[wp.vec3(*N), wp.vec3(*kd), wp.vec3(*ks), e,
                                                      wp.array(np.tile(wo, (len(wi), 1)).astype(np.float32),
                                                               dtype=wp.vec3),
                                                      wp.array(wi.astype(np.float32), dtype=wp.vec3), f, p])
        scale = f.numpy().max()
        assert np.abs(f_l - f.numpy()).max() < 1e-5 * scale  # measured 1.2e-7 relative
        assert np.abs(f_t - f.numpy()).max() < 1e-5 * scale
        assert np.abs(p_l - p.numpy()).max() < 1e-5 * p.numpy().max()  # same roulette weight lum(k_s): measured 8e-8
    # no lobes: Lambert k_d / pi with the cosine density
    lam = MaterialTable.from_specs([{"albedo": kd}])
    f, pdf = _eval(lam, 0, _unit((0.3, 0.0, 0.95)), wi)
    up = wi[:, 2] > 0
    assert np.allclose(f[up], np.asarray(kd) / np.pi, rtol=1e-6) and np.all(f[~up] == 0.0)
    assert np.allclose(pdf, np.maximum(wi[:, 2], 0.0) / np.pi, rtol=1e-5, atol=1e-7)


def test_material_table_rejects_bad_input():
    with pytest.raises(ValueError, match="kd"):
        MaterialTable(np.ones((2, 2)))
    with pytest.raises(ValueError, match="lobes"):
        MaterialTable(np.ones((1, 3)), np.zeros((1, 5, 4)), np.zeros((1, 5, 3)))
    with pytest.raises(ValueError, match="exponent"):
        MaterialTable(np.ones((1, 3)), -np.ones((1, 1, 4)), np.zeros((1, 1, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        MaterialTable(np.full((1, 3), np.nan))


# ---- the BRDF written directly from the material, per direction (the form before shading points): the reference
# the shading-point code must reproduce bit for bit ----


@wp.func
def _direct_eval(mat: MaterialData, m: int, n: wp.vec3, wo: wp.vec3, wi: wp.vec3) -> wp.vec3:
    """f_r (1/sr) of material ``m``: k_d / pi plus its Lafortune lobes; 0 for wi below the surface."""
    if wp.dot(n, wi) <= 0.0:
        return wp.vec3(0.0)
    t, b = orthonormal_basis(n)
    f = mat.kd[m] / wp.pi
    for i in range(mat.lobe_count[m]):
        c = mat.lobes[m, i]
        f += mat.lobe_rho[m, i] * lafortune_lobe(lafortune_axis(n, t, b, wo, c), wi, c[3])
    return f


@wp.func
def _direct_pdf(mat: MaterialData, m: int, n: wp.vec3, wo: wp.vec3, wi: wp.vec3) -> float:
    """Density (1/sr) of _direct_sample: sum over components of P(component) x its density."""
    t, b = orthonormal_basis(n)
    wd = wp.max(luminance(mat.kd[m]), 0.0)
    total = wd
    p = wd * lambert_pdf(n, wi)
    for i in range(mat.lobe_count[m]):
        c = mat.lobes[m, i]
        axis = lafortune_axis(n, t, b, wo, c)
        w = lafortune_lobe_weight(axis, mat.lobe_rho[m, i], c[3])
        if w > 0.0:
            total += w
            p += w * cos_power_pdf(wp.normalize(axis), wi, c[3])
    if not (total > 0.0):
        return 0.0
    return p / total


@wp.func
def _direct_sample(mat: MaterialData, m: int, n: wp.vec3, wo: wp.vec3, xi: wp.vec2, choice: float) -> wp.vec3:
    """Sample material ``m`` (Sec. 5.1): the Russian roulette ``choice`` in [0, 1) picks the diffuse term or a
    lobe with the preintegrated weights, then the cosine / Phong sampler draws wi from ``xi``. A material
    without weight (black) returns the normal, with density 0 (_direct_pdf)."""
    t, b = orthonormal_basis(n)
    wd = wp.max(luminance(mat.kd[m]), 0.0)
    total = wd
    for i in range(mat.lobe_count[m]):
        c = mat.lobes[m, i]
        total += lafortune_lobe_weight(lafortune_axis(n, t, b, wo, c), mat.lobe_rho[m, i], c[3])
    if not (total > 0.0):
        return n
    x = choice * total
    if x < wd:
        return lambert_sample(n, xi)
    acc = wd
    chosen = int(-1)
    last = int(-1)
    for i in range(mat.lobe_count[m]):
        c = mat.lobes[m, i]
        w = lafortune_lobe_weight(lafortune_axis(n, t, b, wo, c), mat.lobe_rho[m, i], c[3])
        if w > 0.0:
            last = i
            acc += w
            if chosen < 0 and x < acc:
                chosen = i
    if chosen < 0:
        chosen = last  # x rounded onto the total
    if chosen < 0:
        return lambert_sample(n, xi)
    c = mat.lobes[m, chosen]
    return cos_power_sample(wp.normalize(lafortune_axis(n, t, b, wo, c)), c[3], xi)


@wp.kernel
def _shading_point_kernel(mat: MaterialData, m: wp.array(dtype=wp.int32), n: wp.array(dtype=wp.vec3),
                          wo: wp.array(dtype=wp.vec3), wi: wp.array(dtype=wp.vec3), xi: wp.array(dtype=wp.vec3),
                          ref: wp.array2d(dtype=wp.float32), got: wp.array2d(dtype=wp.float32)):
    """Row k: f (3), pdf, sample (3), pdf of the sample by the direct formulas (ref) and by one shading_point (got)."""
    k = wp.tid()
    nk = wp.normalize(n[k])
    wok = wp.normalize(wo[k])
    u = wp.vec2(xi[k][0], xi[k][1])
    f = _direct_eval(mat, m[k], nk, wok, wi[k])
    s = _direct_sample(mat, m[k], nk, wok, u, xi[k][2])
    sp = shading_point(mat, m[k], nk, wok)
    g = shading_eval(sp, wi[k])
    t = shading_sample(sp, u, xi[k][2])
    for c in range(3):
        ref[k, c] = f[c]
        got[k, c] = g[c]
        ref[k, 4 + c] = s[c]
        got[k, 4 + c] = t[c]
    ref[k, 3] = _direct_pdf(mat, m[k], nk, wok, wi[k])
    got[k, 3] = shading_pdf(sp, wi[k])
    ref[k, 7] = _direct_pdf(mat, m[k], nk, wok, s)
    got[k, 7] = shading_pdf(sp, t)


def test_shading_point_equals_the_material_functions_bit_for_bit(table):
    """The estimators compute the per-point part of the BRDF once (shading_point); eval, pdf and sample must stay
    exactly the direct per-direction formulas (same images as before the hoisting; material_* wrap the shading
    code, so the tests of material_* above test it too)."""
    phong = MaterialTable.phong(np.float32([[0.4, 0.3, 0.2], [0.5, 0.5, 0.5]]), np.float32([[0.3, 0.3, 0.3],
                                                                                          [0.0, 0.0, 0.0]]), 17.0)
    black = MaterialTable.from_specs([{"albedo": (0.0, 0.0, 0.0)}, {"albedo": (0.0, 0.0, 0.0), "lafortune": [
        {"coefficients": (0.0, 0.0, 0.0), "exponent": 3.0, "color": (1.0, 1.0, 1.0)}]}])
    rng = np.random.default_rng(8)
    k = 20_000
    for t in (table, phong, black):
        n = rng.normal(size=(k, 3)).astype(np.float32)
        wo = rng.normal(size=(k, 3)).astype(np.float32)
        wo *= np.sign(np.sum(wo * n, axis=1))[:, None]
        wi = rng.normal(size=(k, 3))
        wi = (wi / np.linalg.norm(wi, axis=1, keepdims=True)).astype(np.float32)
        xi = rng.random((k, 3)).astype(np.float32)
        m = rng.integers(0, len(t), k).astype(np.int32)
        ref, got = wp.zeros((k, 8), dtype=wp.float32), wp.zeros((k, 8), dtype=wp.float32)
        wp.launch(_shading_point_kernel, dim=k, inputs=[t.device_data(), wp.array(m, dtype=wp.int32),
                                                        *(wp.array(a, dtype=wp.vec3) for a in (n, wo, wi, xi)),
                                                        ref, got], device="cpu")
        assert np.array_equal(ref.numpy(), got.numpy())
        assert np.isfinite(got.numpy()).all()
