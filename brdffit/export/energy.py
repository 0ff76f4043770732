"""How much light an exported material reflects: its directional albedo per incidence.

    albedo(theta_i) = int f(wi, wo) cos_o dw_o   over the upper hemisphere, per channel

A renderer takes a material that reflects more than it receives (albedo > 1) as it is:
the image brightens with every bounce. The target models are bounded by their ranges
(``rough_conductor`` conserves energy by construction), but glTF's own formula weights
its diffuse by ``1 - F(v.h)`` and exceeds 1 towards grazing for bright dielectrics, so
every export reports its largest albedo, and warns where it passes 1.

Integrated over the half vector, where a sharp lobe is narrow but not a spike:
``wo = 2 (wi.h) h - wi``, ``dw_o = 4 (wi.h) dw_h``; ``theta_h = u^2 pi/2`` (MERL's square
root spacing, dense at the peak), midpoint rule in ``u`` and ``phi_h``. Resolves lobes
down to alpha ~ 0.005 to well under 1%; sharper lobes are under-resolved (their albedo
reads low), which the warning threshold tolerates in the safe direction only.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import numpy as np

from brdffit import models, runtime

#: Incidence angles the albedo is evaluated at (degrees).
THETA_I_DEG = (0.0, 30.0, 50.0, 65.0, 75.0, 82.0, 86.0, 89.0)
N_U, N_PHI = 512, 256


@functools.cache
def _directions():
    """wi, wo (n_incidences, N_U * N_PHI, 3) and the weights cos_o 4 (wi.h) dw_h
    (0 where wo is below the horizon) of every incidence."""
    u = (np.arange(N_U) + 0.5) / N_U
    phi = (np.arange(N_PHI) + 0.5) / N_PHI * 2 * np.pi
    uu, pp = np.meshgrid(u, phi, indexing="ij")
    th = uu * uu * np.pi / 2
    h = np.stack([np.sin(th) * np.cos(pp), np.sin(th) * np.sin(pp), np.cos(th)], -1).reshape(-1, 3)
    dw_h = (np.sin(th) * np.pi * uu).reshape(-1) / N_U * (2 * np.pi / N_PHI)
    return mirrored_directions(h, dw_h)


def mirrored_directions(h: np.ndarray, dw_h: np.ndarray):
    """For each incidence of :data:`THETA_I_DEG`, the directions an albedo integral
    over half vectors ``h`` (n, 3) with solid angles ``dw_h`` visits: wi, wo = the
    mirror of wi about each h (+z where it falls below the horizon), and the weight
    cos_o 4 (wi.h) dw_h (0 there), stacked as (n_incidences, n, ...). Shared with the
    coarser grid of ``brdffit.fitting.physical``."""
    wis, wos, weights = [], [], []
    for deg in THETA_I_DEG:
        t = np.radians(deg)
        wi = np.array([np.sin(t), 0.0, np.cos(t)])
        c = h @ wi
        wo = 2 * c[:, None] * h - wi
        ok = (c > 0) & (wo[:, 2] > 0)
        wis.append(np.broadcast_to(wi, wo.shape))
        wos.append(np.where(ok[:, None], wo, [0.0, 0.0, 1.0]))
        weights.append(np.where(ok, wo[:, 2] * 4 * c * dw_h, 0.0))
    return np.stack(wis), np.stack(wos), np.stack(weights)


@eqx.filter_jit
def _albedo(model, params, wi, wo, weight):
    # one incidence at a time: the 131,072 direction pairs of all eight at once
    # would hold ~100 MB of temporaries
    return jax.lax.map(lambda a: a[2] @ model(params, a[0], a[1]), (wi, wo, weight))


@runtime.in_float64
def directional_albedo(model: str, params: dict) -> np.ndarray:
    """Albedo (len(THETA_I_DEG), 3) of ``model`` with ``params`` at each incidence."""
    import jax.numpy as jnp

    m = models.get(model)
    p = {k: jnp.asarray(v) for k, v in m.check_params(params).items()}
    wi, wo, weight = (jnp.asarray(a) for a in _directions())
    return np.asarray(_albedo(m, p, wi, wo, weight))


def energy_report(model: str, params: dict) -> tuple[dict, list[str]]:
    """``{"albedo_max": [r, g, b], "albedo_max_theta_deg": angle}`` and a warning when
    the largest albedo passes 1 (by more than the integration's 0.5%), naming the
    channels and the incidences where it does."""
    a = directional_albedo(model, params)
    i = int(np.argmax(a.max(axis=1)))
    report = {"albedo_max": a[i].tolist(), "albedo_max_theta_deg": THETA_I_DEG[i]}
    warnings = []
    over = a > 1.005
    if over.any():
        channels = [c for c, o in zip("RGB", over.any(axis=0), strict=True) if o]
        angles = [THETA_I_DEG[j] for j in np.flatnonzero(over.any(axis=1))]
        where = (f"at {angles[0]:g} deg" if len(angles) == 1
                 else f"from {angles[0]:g} to {angles[-1]:g} deg")
        warnings.append(
            f"energy: the {model} material reflects up to {a[i].max():.3f} of the light "
            f"arriving at {THETA_I_DEG[i]:g} deg in {'RGB'[int(np.argmax(a[i]))]} "
            f"(directional albedo > 1 in {', '.join(channels)} {where} incidence): a "
            "renderer brightens it with every bounce; a fit with --physical "
            "(physical=True) stays below 1")
    return report, warnings
