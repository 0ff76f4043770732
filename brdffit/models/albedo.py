"""A model's directional albedo per incidence: how much of the light arriving at
theta_i it reflects, over the whole upper hemisphere.

    albedo(theta_i) = int f(wi, wo) cos_o dw_o   over the upper hemisphere, per channel

Used by the physically bounded fit (``brdffit.fitting.physical``: albedo <= 1) and by
every export's energy check (``brdffit.export.energy``); it is a property of a model
and its parameters, so it lives with the models, below both.

Integrated over the half vector, where a sharp lobe is narrow but not a spike:
``wo = 2 (wi.h) h - wi``, ``dw_o = 4 (wi.h) dw_h``; ``theta_h = u^2 pi/2`` (MERL's square
root spacing, dense at the peak), midpoint rule in ``u`` and ``phi_h``. Resolves lobes
down to alpha ~ 0.005 to well under 1%; sharper lobes are under-resolved (their albedo
reads low), which an upper-limit check tolerates in the safe direction only.
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
