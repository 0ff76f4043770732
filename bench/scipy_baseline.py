"""What a user would otherwise write: scipy.optimize.least_squares on the same loss.

A numpy model (``tests/reference_merl.py``, written from docs/models.md), bounded
parameters in TRF, 2-point finite differences, over every usable bin of the table.
The residual is brdffit's (``brdffit.fitting.loss``): sqrt(w) (log1p(f cos_i) - log1p(f_meas
cos_i)) with the same solid-angle weights, so both minimise the same function.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.optimize import least_squares

from brdffit import models
from brdffit.fitting.problem import table_error
from brdffit.fitting.sampling import bin_weights, usable_bins
from brdffit.io.grid import bin_grid
from brdffit.io.merl import MerlTable
from tests.reference_merl import evaluate


def _unflatten(model, x):
    out, i = {}, 0
    for s in model.param_specs:
        out[s.name] = x[i : i + s.size] if s.rgb else float(x[i])
        i += s.size
    return out


def fit_scipy(table: MerlTable, model_name: str, x0_params: dict) -> dict:
    """Fit with scipy; returns time, params, steps (function evaluations) and errors."""
    m = models.get(model_name)
    g = bin_grid()
    usable = usable_bins(table).usable
    idx = np.flatnonzero(usable)
    w = bin_weights(usable)[idx]
    wi, wo, cos_i = g.wi[idx], g.wo[idx], g.cos_i[idx]
    target = np.log1p(table.rgb.reshape(3, -1)[:, idx].T * cos_i[:, None])
    sqrt_w = np.sqrt(w)[:, None]
    lo, hi = [], []
    for s in m.param_specs:
        lo += [s.lower] * s.size
        hi += [np.inf if s.upper is None else s.upper] * s.size
    x0 = np.concatenate([np.broadcast_to(np.asarray(x0_params[s.name], float), (s.size,))
                         for s in m.param_specs])
    x0 = np.clip(x0, np.array(lo) + 1e-9, np.array(hi) - 1e-9)

    def residuals(x):
        with np.errstate(all="ignore"):
            f = evaluate(model_name, _unflatten(m, x), wi, wo)
        return (sqrt_w * (np.log1p(np.maximum(f, 0) * cos_i[:, None]) - target)).ravel()

    t0 = time.perf_counter()
    sol = least_squares(residuals, x0, bounds=(lo, hi), method="trf", x_scale="jac")
    elapsed = time.perf_counter() - t0
    params = {k: (np.asarray(v).tolist() if np.ndim(v) else float(v))
              for k, v in _unflatten(m, sol.x).items()}
    return {
        "time_s": elapsed,
        "params": params,
        "nfev": int(sol.nfev),
        "status": int(sol.status),
        "error": table_error(table, m, params),
    }
