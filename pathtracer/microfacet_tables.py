"""Mitsuba's precomputed tables for ``roughplastic`` (src/bsdfs/roughplastic.cpp, include/mitsuba/render/microfacet.h),
computed here in numpy with the same microfacet model as kernels/bsdfs.py.

- ``external_transmittance(alpha, dist, eta)``: t(mu) at 64 evenly spaced mu = cos(theta_i) in [0, 1] (mu >= 1e-6):
  the share of light arriving at mu that refracts into the coat, over visible normals:
  integral of G1(wt, m) (1 - F(wi.m)) D(m) G1(wi, m) max(0, wi.m) / wi.z dm, wt the refracted direction.
- ``internal_reflectance(alpha, dist, eta)``: 2 mean_k(R(mu_k) mu_k) over the same 64 mu, R the reflectance of the
  coat from inside (relative index 1 / eta), as Mitsuba averages it.

Mitsuba integrates with 32 x 32 Gauss-Legendre points mapped through its visible-normal sampler; this integrates
the same integral over the microfacet normal directly, in a variable that follows the distribution's width.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

RES = 64  # MI_ROUGH_TRANSMITTANCE_RES


def _fresnel(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """Dielectric reflectance for cos_i >= 0 measured on the incident side, relative index eta."""
    ci = np.abs(cos_i)
    ct2 = 1.0 - (1.0 - ci * ci) / (eta * eta)
    ct = np.sqrt(np.maximum(ct2, 0.0))
    a_s = (ci - eta * ct) / (ci + eta * ct)
    a_p = (ct - eta * ci) / (ct + eta * ci)
    f = 0.5 * (a_s * a_s + a_p * a_p)
    return np.where((ct2 <= 0.0) | (ci == 0.0), 1.0, f)


def _d(mz: np.ndarray, tan2: np.ndarray, alpha: float, ggx: bool) -> np.ndarray:
    cos2 = mz * mz
    if ggx:
        return 1.0 / (np.pi * alpha**2 * cos2 * cos2 * (1.0 + tan2 / alpha**2) ** 2)
    return np.exp(-tan2 / alpha**2) / (np.pi * alpha**2 * cos2 * cos2)


def _g1(v: np.ndarray, m: np.ndarray, alpha: float, ggx: bool) -> np.ndarray:
    xy = alpha**2 * (v[..., 0] ** 2 + v[..., 1] ** 2)
    tan2 = xy / np.maximum(v[..., 2] ** 2, 1e-300)
    if ggx:
        g = 2.0 / (1.0 + np.sqrt(1.0 + tan2))
    else:
        a = 1.0 / np.sqrt(np.maximum(tan2, 1e-300))
        g = np.where(a >= 1.6, 1.0, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a))
    g = np.where(xy == 0.0, 1.0, g)
    return np.where(np.sum(v * m, axis=-1) * v[..., 2] <= 0.0, 0.0, g)


def _normals(alpha: float, n: int = 96):
    """Quadrature over the hemisphere of microfacet normals: directions and solid-angle weights; theta follows
    tan(theta) = alpha tan(pi x / 2), x Gauss-Legendre on (0, 1), phi Gauss-Legendre on (0, 2 pi)."""
    x, wx = np.polynomial.legendre.leggauss(n)
    x, wx = 0.5 * (x + 1.0), 0.5 * wx
    p, wp_ = np.polynomial.legendre.leggauss(2 * n)
    phi, wphi = np.pi * (p + 1.0), np.pi * wp_
    t = np.tan(0.5 * np.pi * x)
    theta = np.arctan(alpha * t)
    dtheta = alpha * 0.5 * np.pi * (1.0 + t * t) / (1.0 + alpha * alpha * t * t)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    w = (wx * dtheta * np.sin(theta))[:, None] * wphi[None, :]
    m = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    return m, w, np.tan(th) ** 2


def _mu() -> np.ndarray:
    return np.maximum(1e-6, np.linspace(0.0, 1.0, RES))


def _lobe(alpha: float, ggx: bool, eta: float, transmit: bool) -> np.ndarray:
    m, w, tan2 = _normals(alpha)
    d = _d(m[..., 2], tan2, alpha, ggx)
    out = np.zeros(RES)
    for k, mu in enumerate(_mu()):
        wi = np.array([np.sqrt(1.0 - mu * mu), 0.0, mu])
        c = m @ wi  # wi . m
        vis = d * _g1(wi[None, None, :], m, alpha, ggx) * np.maximum(c, 0.0) / mu
        f = _fresnel(c, eta)
        if transmit:
            ct = np.sqrt(np.maximum(1.0 - (1.0 - c * c) / (eta * eta), 0.0))
            wo = m * (c / eta - ct)[..., None] - wi / eta  # refracted, below the surface
            val = _g1(wo, m, alpha, ggx) * (1.0 - f)
            val = np.where(wo[..., 2] * mu >= 0.0, 0.0, val)
        else:
            wo = 2.0 * c[..., None] * m - wi
            val = _g1(wo, m, alpha, ggx) * f
            val = np.where(wo[..., 2] <= 0.0, 0.0, val)
        out[k] = np.sum(vis * val * w)
    return out


@lru_cache(maxsize=64)
def external_transmittance(alpha: float, dist: str, eta: float) -> np.ndarray:
    return _lobe(max(alpha, 1e-4), dist == "ggx", eta, True)


@lru_cache(maxsize=64)
def internal_reflectance(alpha: float, dist: str, eta: float) -> float:
    r = _lobe(max(alpha, 1e-4), dist == "ggx", 1.0 / eta, False)
    return float(2.0 * np.mean(r * _mu()))
