"""How much light an exported material reflects, and a warning where it is over 1.

A renderer takes a material that reflects more than it receives (albedo > 1) as it is:
the image brightens with every bounce. The target models are bounded by their ranges
(``rough_conductor`` conserves energy by construction), but glTF's own formula weights
its diffuse by ``1 - F(v.h)`` and exceeds 1 towards grazing for bright dielectrics, so
every export reports its largest directional albedo (``brdffit.models.albedo``), and
warns where it passes 1.
"""

from __future__ import annotations

import numpy as np

from brdffit.models.albedo import THETA_I_DEG, directional_albedo


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
            f"energy: the {model} material reflects up to {a[i].max():.4g} of the light "
            f"arriving at {THETA_I_DEG[i]:g} deg in {'RGB'[int(np.argmax(a[i]))]} "
            f"(directional albedo > 1 in {', '.join(channels)} {where} incidence): a "
            "renderer brightens it with every bounce; a fit with --physical "
            "(physical=True) stays below 1")
    return report, warnings
