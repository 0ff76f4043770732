"""What the render loss sees: the views it compares, and each channel's exposure.

The render loss (``loss="render"``, :mod:`brdffit.fitting.loss`) compares the table
and the fit the way a picture of the material does. Both are rendered on a unit
sphere seen orthographically along -z under each of :data:`LIGHTS` (one
directional light at a time, irradiance pi); every point of the picture reads its
MERL bin, for the table and for the fit alike, so the sum over the pictures is a
sum over bins, each weighted by the area of the pictures that reflect in it
(:func:`view_area`, integrated over the sphere's normals, not counted in pixels: a
pixel grid missed the near-mirror peak's bins, where a fit could then put any
energy unseen). That keeps the loss a per-bin least
squares, with the closed-form normal equations of every other loss, on the
solver's usual fixed-size stratified subsample: one compiled fit for every table.

Each rendered radiance is exposed per channel and mapped through a smooth tone
curve (:func:`brdffit.fitting.loss.tone`). The exposures (:func:`exposures`) put
each channel's median rendered radiance at :data:`MID_GREY` of the curve's input:
a von Kries adaptation to the material's own colour, so that a channel 20x
darker than the others (red plastic's blue) counts by its relative error, as the
eye adapted to the material judges it, not by its absolute one.

Three more residuals hold each channel's mean radiance over the views
(``LossData.energy``, ``brdffit.fitting.loss.ENERGY_WEIGHT``): the tone curve alone
lets a glossy fit lose most of its highlight's energy, and with it its colour.

With a scene (``brdffit.fitting.scene``) the scene's direction pairs decide the
views instead: its bin weight is used as it is.
"""

from __future__ import annotations

import functools
import hashlib

import numpy as np

from brdffit.fitting.lit_sphere import bin_areas
from brdffit.io import array_cache
from brdffit.io.angles import SHAPE
from brdffit.io.grid import bin_grid

#: (label, direction in camera space: x right, y up, z towards the viewer). Not
#: the lights of the benchmark: two key lights, a light beside the camera (the
#: head-on, retro-reflective view), two grazing lights and three back lights (the
#: rim, where the Fresnel rise and the shadowing decide). The more directions the
#: views cover, the less a fit is tuned to any one picture: on the 100 real
#: materials, against the log loss's fit, the worst material's independent render
#: went from -2.3 dB (4 lights) to -1.1 (6) to -0.5 (8) (docs/fitting.md), at no
#: cost per step (the subsample's size is fixed).
LIGHTS = (
    ("key, 40 deg above-left", np.array([-0.45, 0.45, 0.77])),
    ("beside the camera", np.array([0.1, -0.1, 0.99])),
    ("grazing from the right, 78 deg", np.array([0.98, 0.0, 0.21])),
    ("back light from above-behind", np.array([0.25, 0.55, -0.8])),
    ("key, 50 deg below-right", np.array([0.6, -0.5, 0.62])),
    ("back light from the left, low", np.array([-0.9, -0.1, -0.42])),
    ("grazing from below, 64 deg", np.array([0.0, -0.9, 0.44])),
    ("back light from the right", np.array([0.5, 0.2, -0.84])),
)
#: Quadrature of the views (:func:`brdffit.fitting.lit_sphere.bin_areas`): Gauss nodes
#: per theta_h bin, azimuths per degree. Against a rule twice as fine each way, its
#: weights are off by 0.19% of their sum, and it leaves out 263 of the 104,552 bins the
#: eight views reflect in (their edges'); a 256-px picture of each view was off by 25%
#: and left out 41,283, the peak rows' among them.
VIEW_NODES = (2, 2)
#: A channel's median rendered radiance is exposed to this (Reinhard maps it to 0.26).
MID_GREY = 0.35
#: The exposed level is at least this fraction of the channel's mean (see :func:`exposures`).
MEAN_FLOOR = 0.1
#: No channel is exposed more than this times the brightest channel.
MAX_CHANNEL_GAIN = 30.0


#: Bumped when :func:`view_bin_weight`'s quadrature changes: the views kept in brdffit's
#: cache directory are then computed again.
_VIEWS_VERSION = 1


@functools.cache
def view_area() -> np.ndarray:
    """The area of the pictures of :data:`LIGHTS` that each flat MERL bin covers
    (``(n . v) dOmega_n`` over the lit, visible normals whose directions fall in it,
    summed over the lights: a pixel count's limit), read-only, the same for every
    table. Computed once per machine (~0.3 s) and kept in brdffit's cache directory."""
    key = repr(([tuple(light) for _, light in LIGHTS], VIEW_NODES, SHAPE)).encode()
    name = f"render-views-v{_VIEWS_VERSION}-{hashlib.sha256(key).hexdigest()[:16]}"

    def compute():
        return {"area": sum(bin_areas(light, *VIEW_NODES, lit_by=False)
                            for _, light in LIGHTS)}

    return array_cache.load_or_compute(name, ("area",), compute)["area"]


@functools.cache
def view_bin_weight() -> np.ndarray:
    """The views as a ``bin_weight`` (``fit(..., bin_weight=)``'s sense, which
    multiplies the solid-angle weight): area over solid-angle weight, so that the
    fit's weights are the areas of :func:`view_area`. A bin that no view reflects in,
    or whose centre is below the horizon, gets 0."""
    solid = bin_grid().weight
    area = view_area()
    w = np.where(solid > 0, area / np.where(solid > 0, solid, 1.0), 0.0)
    w /= w[w > 0].mean()
    w.setflags(write=False)
    return w


def exposures(values_cos: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Per channel, the exposure ``e_c`` (3, 1) that puts the weighted median of
    ``e_c f cos_i`` (``values_cos``, (3, S), 0 where unmeasured) at :data:`MID_GREY`:
    the median rendered radiance (irradiance pi, exposure ``e_c / pi``) at
    :data:`MID_GREY`, the table's own colour adaptation, data passed to the loss.

    Two floors keep it a picture: a near-mirror (chrome) is black at most pixels, and
    its median says nothing of what a viewer adapts to, so the level exposed is at
    least :data:`MEAN_FLOOR` of the channel's mean (the highlight's energy); and no
    channel is exposed more than :data:`MAX_CHANNEL_GAIN` times the brightest one
    (a channel that is black but for noise is not blown up to mid grey)."""
    used = weight > 0
    if not used.any():
        return np.ones((3, 1))
    w = weight[used] / weight[used].sum()
    med = np.array([_weighted_median(v[used], w) for v in values_cos])
    mean = values_cos[:, used] @ w
    level = np.maximum(med, MEAN_FLOOR * mean)
    level = np.maximum(level, max(float(level.max()), 1e-12) / MAX_CHANNEL_GAIN)
    return (MID_GREY / level)[:, None]


def _weighted_median(values: np.ndarray, weight: np.ndarray) -> float:
    if values.size == 0:
        return 0.0
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weight[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])
