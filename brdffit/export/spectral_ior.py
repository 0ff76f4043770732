"""A conductor's ``eta``, ``k`` as spectra that mean in Mitsuba 3's spectral variants what
the RGB triples mean in its RGB variants.

An RGB variant evaluates the conductor Fresnel per channel, F(eta_c, k_c, cos_d). A
spectral variant evaluates it per wavelength and its film projects the result onto
sRGB (:mod:`brdffit.io.srgb_response`): channel c sees
``int w_c F(eta(lambda), k(lambda), cos_d) d lambda``. The Fresnel is not linear in
eta, k, and w_c overlap and go negative, so no upsampling of the triples themselves
keeps the colour; :func:`fit_spectra` instead fits eta, k at :data:`NODES` wavelengths
(Mitsuba's ``regular`` spectrum: linear between them) so that the projected Fresnel
matches the RGB one over cos_d in [0, 1], relative error per channel (floored at
F = 0.01), by Levenberg-Marquardt in float64 with a light smoothness penalty (it
only steers the wavelengths no channel sees). Equal channels need no fit: a constant
spectrum is exact.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from brdffit import runtime
from brdffit.io import srgb_response

#: Node wavelengths (nm) of the fitted spectra: Mitsuba's range, every 15.2 nm.
NODES = np.linspace(360.0, 830.0, 32)
#: Wavelengths the projection integrates on (nm): every 2 nm.
_LAMBDA = np.linspace(360.0, 830.0, 236)
#: cos_d where the projected Fresnel is matched: uniform, and dense towards 1, where
#: an eta < 1 puts its critical angle (cos_d = sqrt(1 - eta^2), 0.998 for eta 0.06).
#: Not below 0.01: at cos_d = 0 the Fresnel of eta = 1, k = 0 jumps from 0 to 1.
COS_D = np.unique(np.concatenate([np.linspace(0.01, 1.0, 21),
                                  1.0 - np.geomspace(1e-4, 0.03, 8)]))
#: The grids the reported error is measured on, finer than the fit's (Mitsuba
#: integrates over continuous wavelengths and angles): every 0.5 nm, cos_d by 0.01
#: and down to 1e-5 from 1.
_CHECK_LAMBDA = np.linspace(360.0, 830.0, 941)
_CHECK_COS_D = np.unique(np.concatenate([np.linspace(0.01, 1.0, 100),
                                        1.0 - np.geomspace(1e-5, 0.01, 30)]))
#: Relative errors are taken against max(F, FLOOR): a channel reflecting less than 1%
#: is matched to 1e-4 absolute, not relatively.
FLOOR = 0.01
SMOOTHNESS = 1e-2
MAX_STEPS = 300


@dataclass(frozen=True)
class SpectralIOR:
    """eta, k at :data:`NODES` (Mitsuba ``regular`` spectra over [360, 830] nm), and
    ``error``: :func:`fresnel_error` of the spectra, measured on grids finer than
    the fit's (0 when the channels are equal)."""

    eta: np.ndarray
    k: np.ndarray
    error: float


def conductor_fresnel_np(eta, k, cos_d):
    """Mitsuba's conductor Fresnel (``brdffit.models.renderer_terms``) in numpy float64."""
    from brdffit.models.renderer_terms import conductor_fresnel

    with runtime.float64():
        return np.asarray(conductor_fresnel(np.asarray(eta, float), np.asarray(k, float),
                                            np.asarray(cos_d, float)))


def _interp_matrix(wavelengths=_LAMBDA) -> np.ndarray:
    """(len(wavelengths), len(NODES)): linear interpolation of node values."""
    eye = np.eye(NODES.size)
    return np.stack([np.interp(wavelengths, NODES, e) for e in eye], axis=1)


def _quadrature(wavelengths=_LAMBDA) -> np.ndarray:
    """(3, len(wavelengths)): trapezoid weights times w_c, each row summing to 1."""
    dl = np.gradient(wavelengths)
    dl[0] *= 0.5
    dl[-1] *= 0.5
    return (srgb_response.responses(wavelengths) * dl[:, None]).T


def projected_fresnel(eta_nodes, k_nodes, cos_d, wavelengths=_CHECK_LAMBDA) -> np.ndarray:
    """(len(cos_d), 3): the sRGB projection of the spectral Fresnel of ``regular``
    spectra with values ``eta_nodes``, ``k_nodes`` at :data:`NODES` (integrated on
    ``wavelengths``)."""
    lerp = _interp_matrix(wavelengths)
    eta = lerp @ np.asarray(eta_nodes, float)
    k = lerp @ np.asarray(k_nodes, float)
    f = conductor_fresnel_np(eta[None, :], k[None, :], np.asarray(cos_d, float)[:, None])
    return f @ _quadrature(wavelengths).T


def fresnel_error(eta_nodes, k_nodes, eta, k) -> float:
    """Largest relative error (floored at :data:`FLOOR`) over channels and cos_d in
    [0, 1] of the spectra's projected Fresnel against the triples' RGB one."""
    target = conductor_fresnel_np(np.asarray(eta, float)[None, :], np.asarray(k, float)[None, :],
                                  _CHECK_COS_D[:, None])
    got = projected_fresnel(eta_nodes, k_nodes, _CHECK_COS_D)
    return float(np.max(np.abs(got - target) / np.maximum(target, FLOOR)))


@functools.cache
def _solver():
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import optimistix as optx

    from brdffit.models.renderer_terms import conductor_fresnel

    @jax.custom_jvp
    def fresnel(eta, k, cos_d):
        return conductor_fresnel(eta, k, cos_d)

    @fresnel.defjvp
    def fresnel_jvp(primals, tangents):
        # F at (cos_d, lambda) depends on eta(lambda), k(lambda) alone: two elementwise
        # derivatives serve every column of the Jacobian (jacfwd would push each of the
        # 2 x len(NODES) tangents through the whole Fresnel)
        eta, k, cos_d = primals
        t_eta, t_k, _ = tangents
        f, d_eta = jax.jvp(lambda e: conductor_fresnel(e, k, cos_d), (eta,), (jnp.ones_like(eta),))
        _, d_k = jax.jvp(lambda x: conductor_fresnel(eta, x, cos_d), (k,), (jnp.ones_like(k),))
        return f, d_eta * t_eta + d_k * t_k

    def unpack(u):
        n = NODES.size
        return jnp.exp(u[:n]), u[n:] * u[n:]

    def residuals(u, args):
        lerp, quad, cos_d, target, scale = args
        eta, k = unpack(u)
        f = fresnel((lerp @ eta)[None, :], (lerp @ k)[None, :], cos_d[:, None])
        fit = (f @ quad.T - target) / scale
        rough = jnp.concatenate([jnp.diff(u[:NODES.size], 2), jnp.diff(u[NODES.size:], 2)])
        return fit.ravel(), SMOOTHNESS * rough

    solver = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-10)

    @eqx.filter_jit
    def solve(u0, args):
        sol = optx.least_squares(residuals, solver, u0, args=args, max_steps=MAX_STEPS,
                                 throw=False)
        return sol.value

    return solve, unpack


def _start(eta, k) -> np.ndarray:
    """Each node takes the triple's values blended by the channels' positive response
    there (eta in log)."""
    w = np.clip(srgb_response.responses(NODES), 0.0, None) ** 2
    w = w / np.maximum(w.sum(axis=1, keepdims=True), 1e-30)
    log_eta = w @ np.log(eta)
    sqrt_k = np.sqrt(w @ k)
    return np.concatenate([log_eta, sqrt_k])


def fit_spectra(eta, k) -> SpectralIOR:
    """eta, k spectra (values at :data:`NODES`) whose projected Fresnel is the RGB
    triples' ``F(eta_c, k_c, cos_d)``, and how close it came. Cached per triple (an
    export writes the dictionary and its XML from one fit)."""
    return _fit_spectra(tuple(float(x) for x in np.ravel(eta)),
                        tuple(float(x) for x in np.ravel(k)))


@functools.lru_cache(maxsize=256)
def _fit_spectra(eta: tuple, k: tuple) -> SpectralIOR:
    eta = np.asarray(eta)
    k = np.asarray(k)
    if np.all(eta == eta[0]) and np.all(k == k[0]):
        return SpectralIOR(np.full(NODES.size, eta[0]), np.full(NODES.size, k[0]), 0.0)
    target = conductor_fresnel_np(eta[None, :], k[None, :], COS_D[:, None])
    scale = np.maximum(target, FLOOR)
    solve, unpack = _solver()
    with runtime.float64():
        import jax.numpy as jnp

        args = tuple(jnp.asarray(a) for a in (_interp_matrix(), _quadrature(), COS_D,
                                              target, scale))
        u = solve(jnp.asarray(_start(eta, k)), args)
        eta_n, k_n = (np.asarray(a) for a in unpack(u))
    eta_n.flags.writeable = False
    k_n.flags.writeable = False
    return SpectralIOR(eta_n, k_n, fresnel_error(eta_n, k_n, eta, k))


@functools.lru_cache(maxsize=1)
def _reflectance_system():
    """The projection (3, NODES) of node values to linear sRGB, and a second-difference
    penalty that keeps a reflectance spectrum smooth."""
    return _quadrature() @ _interp_matrix(), np.diff(np.eye(NODES.size), 2, axis=0)


def fit_reflectance(rgb, steps: int = 4000) -> np.ndarray:
    """A smooth reflectance spectrum (values in [0, 1] at :data:`NODES`) whose sRGB
    projection in Mitsuba's spectral variants is ``rgb``: bounded least squares by
    projected gradient (a 32-value problem). Mitsuba's own ``rgb`` upsampling is right
    to the eye, not in relative terms where a colour is dark and saturated (a diffuse
    kd = [0, 0, 0.002] came out 8% too blue on a sphere); this one is, to ~1e-5."""
    project, smooth = _reflectance_system()
    a = np.vstack([project, np.sqrt(SMOOTHNESS * 0.1) * smooth])
    b = np.concatenate([np.asarray(rgb, float), np.zeros(smooth.shape[0])])
    h, g = a.T @ a, a.T @ b
    step = 1.0 / np.linalg.eigvalsh(h).max()
    r = np.clip(np.linalg.lstsq(a, b, rcond=None)[0], 0.0, 1.0)
    for _ in range(steps):
        r = np.clip(r - step * (h @ r - g), 0.0, 1.0)
    return r


def reflectance_error(values, rgb) -> float:
    """Largest per-channel error of the spectrum's projection against ``rgb``, relative
    to the brightest channel (a dark channel beside a bright one needs no more)."""
    project, _ = _reflectance_system()
    rgb = np.asarray(rgb, float)
    return float(np.max(np.abs(project @ values - rgb)) / max(rgb.max(), 1e-12))
