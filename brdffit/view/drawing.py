"""What every brdffit figure draws with: the channels' colours, the fitted model at
direction pairs, a measured file's name as a title shows it, the square-root degree
axis, and a figure as PNG bytes. :mod:`brdffit.view.plots` (a table's figures and the
one-page report) and :mod:`brdffit.view.sample_plot` (a sample list's) both use them,
and the report draws a sample list's panels: kept here, below both, the two need not
import each other.
"""

from __future__ import annotations

import io
import os

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from brdffit import models, runtime
from brdffit.fitting.result import FitResult

CHANNELS = (("R", "#d62728"), ("G", "#2ca02c"), ("B", "#1f77b4"))
#: Rec. 709 luminance weights, for the one-curve-per-angle plots.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
NO_DATA = "#b0b0b0"
DPI = 110


def as_result(result: FitResult | dict) -> FitResult:
    return result if isinstance(result, FitResult) else FitResult.from_dict(result)


@eqx.filter_jit
def _model_values(model, params, wi, wo):
    return model(params, wi, wo)


@runtime.in_float64
def evaluate(result: FitResult | dict, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The fitted model at direction pairs (..., 3) -> f_r (..., 3); NaN below the horizon.

    Compiled once per (model, batch shape): each plot calls it with fixed shapes
    (all bins above the horizon, all pixels), whatever the table's mask.
    """
    r = as_result(result)
    model = models.get(r.model)
    params = {k: jnp.asarray(v) for k, v in r.param_arrays().items()}
    f = np.asarray(_model_values(model, params, jnp.asarray(wi), jnp.asarray(wo)),
                   dtype=np.float64)
    above = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    return np.where(above[..., None], f, np.nan)


def source_name(source: str) -> str:
    """A measured file's name as a plot's title shows it. The name is the uploader's
    text: matplotlib would parse "$...$" in it as math, and fail on an unbalanced one.
    An escaped dollar is a literal dollar."""
    return (os.path.basename(source) or source).replace("$", r"\$")


def png_bytes(fig) -> bytes:
    """A matplotlib figure as PNG bytes, at :data:`DPI` on white."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, facecolor="white")
    return buf.getvalue()


def sqrt_degree_axis(ax, axis: str = "x", ticks=(0, 1, 5, 10, 20, 40, 60, 90)) -> None:
    """Square-root degree axis: the table's theta_h spacing."""
    functions = (lambda d: np.sqrt(np.maximum(d, 0.0)), lambda s: np.square(s))
    if axis == "x":
        ax.set_xscale("function", functions=functions)
        ax.set_xlim(0, 90)
        ax.set_xticks(ticks)
    else:
        ax.set_yscale("function", functions=functions)
        ax.set_ylim(0, 90)
        ax.set_yticks(ticks)
