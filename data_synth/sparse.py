"""Sparse sample lists, as gonioreflectometers measure them, with known truth.

``sample_model(model, params, layout, n)`` and ``sample_material(name, layout, n)``
give :class:`~brdffit.io.measurements.Measurements` of an analytic model or of a
shipped real material (its published network, ``data_synth.nbrdf``) at the
directions of one of :data:`LAYOUTS`:

- ``in_plane``: the light at 0, 15, ..., 75 degrees in one azimuth, the view swept
  through the plane of incidence from -85 to 85 degrees (a classic goniometer's
  in-plane scan; the mirror direction is on the swept line);
- ``cornell``: the light on three rings (15, 35, 55 degrees) in one azimuth, the view
  anywhere above the horizon, uniformly in projected solid angle (as Cornell's
  gonioreflectometer files hold them);
- ``uniform``: light and view each uniform in solid angle over the hemisphere, down
  to 85 degrees.

``noise``: multiplicative Gaussian, value * max(0, 1 + noise N(0, 1)), as
``data_synth.synth`` degrades tables; ``sigma=True`` records noise * value as each
sample's standard deviation (at least noise * :data:`SIGMA_FLOOR`: a value of 0, a real
material's dark channel, has an instrument's floor, and a sigma of 0 is refused by the
readers). Write them with ``brdffit.io.writers.write_samples`` (any
layout, by suffix).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from brdffit import models, runtime
from brdffit.io.angles import dirs_to_half_diff
from brdffit.io.measurements import Measurements

LAYOUTS = ("in_plane", "cornell", "uniform")
#: The largest polar angle (degrees) a layout measures at.
MAX_THETA_DEG = 85.0


def layout_angles(layout: str, n: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    """(theta_i, phi_i, theta_o, phi_o) in radians of ``n`` samples of ``layout``
    (``in_plane``: its six scans share them, the first ``n % 6`` one sample more; at
    least 2 a scan, so ``n`` >= 12; it wrote 198 samples for 200, 12 for 7)."""
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    lights = np.radians(np.arange(0.0, 76.0, 15.0))
    least = 2 * lights.size if layout == "in_plane" else 1
    if n < least:
        raise ValueError(f"n must be >= {least}{' (2 a scan of its 6 lights)' if least > 1 else ''}"
                         f" for layout {layout}, got {n}")
    rng = np.random.default_rng(seed)
    top = np.radians(MAX_THETA_DEG)
    if layout == "in_plane":
        per = [n // lights.size + (k < n % lights.size) for k in range(lights.size)]
        theta_i = np.repeat(lights, per)
        signed = np.concatenate([np.linspace(-top, top, m) for m in per])
        # the view on the far side of the normal (phi = 180 deg) holds the mirror
        return (theta_i, np.zeros_like(theta_i), np.abs(signed),
                np.where(signed >= 0, np.pi, 0.0))
    if layout == "cornell":
        theta_i = rng.choice(np.radians([15.0, 35.0, 55.0]), n)
        phi_i = np.zeros(n)
        theta_o = np.arccos(np.sqrt(rng.uniform(np.cos(top) ** 2, 1.0, n)))
        return theta_i, phi_i, theta_o, rng.uniform(0.0, 2 * np.pi, n)
    theta_i, theta_o = (np.arccos(rng.uniform(np.cos(top), 1.0, n)) for _ in range(2))
    return theta_i, rng.uniform(0.0, 2 * np.pi, n), theta_o, rng.uniform(0.0, 2 * np.pi, n)


#: The least value (1/sr) a recorded sigma is made from (module docstring).
SIGMA_FLOOR = 1e-6


def _degraded(values: np.ndarray, noise: float, sigma: bool, rng):
    if noise < 0:
        raise ValueError(f"noise must be >= 0, got {noise}")
    if sigma and noise == 0:
        raise ValueError("sigma=True records noise * value: give a noise > 0")
    noisy = values * np.maximum(0.0, 1.0 + noise * rng.standard_normal(values.shape))
    return noisy, (noise * np.maximum(values, SIGMA_FLOOR) if sigma else None)


@runtime.in_float64
def sample_model(model: str, params: dict | None = None, layout: str = "cornell",
                 n: int = 2000, *, noise: float = 0.0, sigma: bool = False,
                 seed: int = 0) -> tuple[Measurements, dict]:
    """Samples of ``model`` (``params`` over ``data_synth.synth.DEFAULT_PARAMS``):
    ``(measurements, truth)``, ``truth`` the params as the model checked them."""
    from brdffit.io.measurements import direction
    from data_synth.synth import DEFAULT_PARAMS

    m = models.get(model)
    truth = m.check_params({**DEFAULT_PARAMS.get(m.name, {}), **(params or {})})
    angles = layout_angles(layout, n, seed)
    p = {k: jnp.asarray(v) for k, v in truth.items()}
    values = np.asarray(m(p, jnp.asarray(direction(*angles[:2])),
                          jnp.asarray(direction(*angles[2:]))), np.float64)
    rng = np.random.default_rng(seed + 7)
    values, sd = _degraded(values, noise, sigma, rng)
    truth = {k: np.asarray(v).tolist() for k, v in truth.items()}
    meas = Measurements.from_angles(*angles, values, sd, source=f"{model}-{layout}",
                                    provenance={"format": "synthetic", "layout": layout})
    return meas, truth


def sample_material(name: str, layout: str = "cornell", n: int = 2000, *,
                    noise: float = 0.0, sigma: bool = False, seed: int = 0) -> Measurements:
    """Samples of the shipped real material ``name`` (``data_synth.nbrdf``)."""
    from brdffit.io.measurements import direction
    from data_synth import nbrdf

    angles = layout_angles(layout, n, seed)
    wi, wo = direction(*angles[:2]), direction(*angles[2:])
    theta_h, theta_d, phi_d = dirs_to_half_diff(wi, wo)
    # the tables' reciprocity: phi_d and phi_d + 180 deg are one bin (the network was
    # trained on [0, 180) deg)
    values = nbrdf.evaluate(nbrdf.load_weights(name),
                            nbrdf.network_input(theta_h, theta_d, np.mod(phi_d, np.pi)))
    rng = np.random.default_rng(seed + 7)
    values, sd = _degraded(values, noise, sigma, rng)
    return Measurements.from_angles(*angles, values, sd, source=f"{name}-{layout}",
                                    provenance={"format": "synthetic", "layout": layout,
                                                "material": name})
