"""Directional albedo (brdffit.models.albedo, and the export energy check) over the half vector,
against closed forms and a brute-force integral over the outgoing direction."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from brdffit import models
from brdffit.models.albedo import THETA_I_DEG, directional_albedo
from tests.compiled_models import evaluate

pytestmark = pytest.mark.unit


def test_lambert_albedo_is_kd_at_every_incidence():
    a = directional_albedo("lambert", {"kd": [0.2, 0.5, 1.0]})
    np.testing.assert_allclose(a, np.broadcast_to([0.2, 0.5, 1.0], a.shape), rtol=1e-4)


def _brute_force(model, params, theta_deg, n=1500):
    """Midpoint rule over (cos_o, phi_o): slow, independent of the half-vector mapping."""
    m = models.get(model)
    p = {k: jnp.asarray(v) for k, v in m.check_params(params).items()}
    mu = (np.arange(n) + 0.5) / n
    phi = (np.arange(n) + 0.5) / n * 2 * np.pi
    mm, pp = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - mm**2)
    wo = np.stack([s * np.cos(pp), s * np.sin(pp), mm], -1).reshape(-1, 3)
    t = np.radians(theta_deg)
    wi = np.broadcast_to([np.sin(t), 0.0, np.cos(t)], wo.shape)
    f = np.asarray(evaluate(m, p, wi, wo))  # one compiled program, not op by op
    return (f * wo[:, 2:3]).sum(0) / n * (2 * np.pi / n)


@pytest.mark.parametrize("model, params", [
    ("ggx", {"kd": 0.0, "ks": 1.0, "alpha": 0.2, "f0": 1.0}),
    ("gltf_pbr", {"base_color": [1.0, 0.6, 0.2], "metallic": 0.3, "roughness": 0.5}),
])
def test_matches_a_brute_force_integral(model, params):
    a = directional_albedo(model, params)
    for j in (0, len(THETA_I_DEG) - 3, len(THETA_I_DEG) - 1):
        np.testing.assert_allclose(a[j], _brute_force(model, params, THETA_I_DEG[j]), rtol=5e-3)
