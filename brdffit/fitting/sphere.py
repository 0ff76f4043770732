"""Sphere renders of a table and of a model, and the image error between them.

A unit sphere seen orthographically along -z, lit by a directional light of
irradiance pi (a white Lambertian surface facing the light has radiance 1): the
picture a renderer would make of the material. Pixels read the table through its
reference nearest-bin lookup (:meth:`MerlTable.lookup`; NaN where unmeasured) and
the model through JAX. Two lights, as in ``brdffit.view.plots``: a key light 45 deg
above-left and a grazing light from the right (80 deg), which shows the Fresnel
rise.

The image error is the PSNR of the tone-mapped renders (Reinhard, then the sRGB
curve, one exposure per light taken from the table's own render, as the plots
show them), over the lit, measured pixels of both lights:

    PSNR = 10 log10(1 / MSE)  [dB],  capped at 100 dB (identical images).

Tone mapping first: a difference the eye cannot see inside a blown-out highlight
should not dominate the score, and a visible error in the dark diffuse part should
count.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from brdffit import executables, runtime
from brdffit.io.angles import SHAPE, dirs_to_half_diff, half_diff_to_bins
from brdffit.io.merl import MerlTable
from brdffit.models import AbstractBRDFModel

#: (label, light direction in camera space: x right, y up, z towards the viewer)
LIGHTS = (
    ("key light 45° above-left", np.array([-0.5, 0.5, 0.7071])),
    ("grazing light from the right (80°)", np.array([0.9848, 0.0, 0.1736])),
)
#: Rec. 709 luminance weights, for the exposure.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
PSNR_CAP_DB = 100.0


def sphere_directions(size: int, light: np.ndarray):
    """Per-pixel local (wi, wo) (size, size, 3) and the mask of lit, visible pixels
    (read-only arrays, shared: every fit's PSNR renders the same two spheres)."""
    return _sphere_directions(size, tuple(float(c) for c in np.ravel(light)))


@functools.lru_cache(maxsize=16)
def _sphere_directions(size: int, light: tuple[float, ...]):
    wi, wo, inside = sphere_disc(size, np.array(light))
    lit = inside & (wi[..., 2] > 0) & (wo[..., 2] > 0)
    for a in (wi, wo, lit):
        a.setflags(write=False)
    return wi, wo, lit


def sphere_disc(size: int, light: np.ndarray):
    """Per-pixel local (wi, wo) and the mask of pixels on the sphere's disc.

    The tangent frame at each pixel is arbitrary about the normal: the tables are
    isotropic, so only the angles between wi, wo and the normal matter.
    """
    s = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(s, -s)
    inside = x * x + y * y < 1.0
    n = np.stack([x, y, np.sqrt(np.clip(1.0 - x * x - y * y, 0.0, 1.0))], axis=-1)
    up = np.where(np.abs(n[..., 1:2]) < 0.99, [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    t = np.cross(up, n)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    b = np.cross(n, t)
    frame = np.stack([t, b, n], axis=-2)  # rows: local x, y, z axes
    wi = frame @ (light / np.linalg.norm(light))
    wo = frame @ np.array([0.0, 0.0, 1.0])
    return wi, wo, inside


def radiance(f: np.ndarray, wi: np.ndarray, xp=np) -> np.ndarray:
    """Outgoing radiance of BRDF values ``f`` under irradiance pi from ``wi``
    (``xp``: numpy, or ``jax.numpy`` inside a compiled function)."""
    return f * np.pi * xp.clip(wi[..., 2:3], 0.0, None)


def tonemap(rad: np.ndarray, exposure, xp=np) -> np.ndarray:
    """Reinhard, then the sRGB curve: highlights compress, nothing clips; in [0, 1)
    (``xp``: numpy, or ``jax.numpy`` inside a compiled function)."""
    x = xp.maximum(rad * exposure, 0.0)
    x = x / (1.0 + x)
    return xp.where(x <= 0.0031308, 12.92 * x, 1.055 * xp.power(x, 1 / 2.4) - 0.055)


def render_table(table: MerlTable, light: np.ndarray, size: int = 128):
    """Radiance image of the table (NaN where the bin is unmeasured) and its lit mask:
    :meth:`MerlTable.lookup` at every lit pixel, through the pixels' bins, which are
    the same for every table."""
    wi, wo, lit = sphere_directions(size, light)
    bins = _sphere_bins(size, tuple(float(c) for c in np.ravel(light)))
    values = table.rgb.reshape(3, -1)[:, bins]
    img = np.zeros((size, size, 3))
    img[lit] = np.where(table.mask.reshape(-1)[bins], values, np.nan).T
    return radiance(img, wi), lit


@functools.lru_cache(maxsize=16)
def _sphere_bins(size: int, light: tuple[float, ...]) -> np.ndarray:
    """Flat MERL bin of each lit pixel (in ``lit``'s order), as ``lookup`` finds it."""
    wi, wo, lit = _sphere_directions(size, light)
    bins = np.ravel_multi_index(half_diff_to_bins(*dirs_to_half_diff(wi[lit], wo[lit])), SHAPE)
    bins.setflags(write=False)
    return bins


@runtime.in_float64
def render_model(model: AbstractBRDFModel, params: dict, light: np.ndarray, size: int = 128):
    """Radiance image of a model with ``params`` (docs/models.md names) and its lit mask."""
    wi, wo, lit = sphere_directions(size, light)
    p = {k: np.asarray(v, dtype=np.float64) for k, v in params.items()}
    f = np.asarray(evaluate(model, p, wi, wo), dtype=np.float64)
    return _lit_radiance(f, wi, lit), lit


def _lit_radiance(f: np.ndarray, wi: np.ndarray, lit: np.ndarray) -> np.ndarray:
    """The radiance image of BRDF values ``f`` on a sphere's pixels, 0 where unlit."""
    return radiance(np.where(lit[..., None], f, 0.0), wi)


@executables.jit(compiled_forms=False)
def evaluate(model, params, wi, wo):
    """``model(params, wi, wo)``, compiled once per model and shape and kept on disk
    (``brdffit.executables``). The model's own program, not its family's
    (``brdffit.models.base.share_programs``): ``auto`` times it as a renderer's cost per sample."""
    return model(params, wi, wo)


class SphereReference:
    """A table's renders, made once, to score any number of models against.

    ``psnr(model, params)`` is the image error of the module docstring.
    """

    def __init__(self, table: MerlTable, size: int = 128, lights=LIGHTS):
        self.size = size
        self.lights = [light for _, light in lights]
        self.images, self.masks, self.exposures = [], [], []
        for light in self.lights:
            rad, lit = render_table(table, light, size)
            ok = lit & np.all(np.isfinite(rad), axis=-1)
            typical = float(np.median(rad[ok] @ LUMINANCE)) if ok.any() else 1.0
            exposure = 0.35 / max(typical, 1e-6)
            self.images.append(tonemap(np.nan_to_num(rad), exposure))
            self.masks.append(ok)
            self.exposures.append(exposure)
        self._scored = None  # made on the first psnr
        # the colour error's sphere (no reference to the table itself is kept: a
        # reference is cached per table, weakly)
        key = LIGHTS[0][1]
        self._colour = (*sphere_directions(COLOUR_SIZE, key),
                        render_table(table, key, COLOUR_SIZE)[0])

    @runtime.in_float64
    def psnr(self, model: AbstractBRDFModel, params: dict) -> float:
        return self.psnr_and_colour(model, params)[0]

    @runtime.in_float64
    def psnr_and_colour(self, model: AbstractBRDFModel, params: dict,
                        ) -> tuple[float, list[float | None]]:
        """The PSNR and :func:`sphere_colour_error`, from one evaluation of the model
        (one compiled program per model: a new process's fit compiled two)."""
        wi_c, wo_c, lit_c, ref_c = self._colour
        if self._scored is None:
            # every lit pixel of both lights (a shape fixed by the size: one compiled
            # score for every table), the measured ones weighted 1
            parts = []
            for light, ref, ok, exposure in zip(self.lights, self.images, self.masks,
                                                self.exposures, strict=True):
                wi, wo, lit = sphere_directions(self.size, light)
                parts.append((wi[lit], wo[lit], ref[lit], ok[lit].astype(np.float64),
                              np.full(int(lit.sum()), exposure)))
            self._scored = tuple(np.concatenate(a) for a in zip(*parts))
        n = 3 * int(self._scored[3].sum())
        p = {k: np.asarray(v, dtype=np.float64) for k, v in params.items()}
        se, finite, f_c = _sphere_measures(model, p, *self._scored, wi_c, wo_c)
        colour = _colour_error(_lit_radiance(np.asarray(f_c, np.float64), wi_c, lit_c),
                               lit_c, ref_c)
        if n == 0 or not bool(finite):
            return float("nan"), colour
        mse = float(se) / n
        psnr = PSNR_CAP_DB if mse <= 10 ** (-PSNR_CAP_DB / 10) else float(-10 * np.log10(mse))
        return psnr, colour


#: Pixels per side of the key-light sphere behind :func:`sphere_colour_error`.
COLOUR_SIZE = 64


@executables.jit
def _sphere_measures(model, params, wi, wo, ref, scored, exposure, wi_c, wo_c):
    """Sum of squared differences between the model's tone-mapped render and ``ref``
    over the ``scored`` pixels (weight 1; 0 elsewhere), whether every scored one is
    finite, and the model's values at ``(wi_c, wo_c)`` (the colour error's sphere):
    :func:`render_model`, :func:`radiance` and :func:`tonemap` in one compiled call
    (~0.5 ms instead of ~2.5 ms of numpy around the model), the model evaluated once
    over both sets of directions."""
    n = wi.shape[0]
    f = model(params, jnp.concatenate([wi, wi_c.reshape(-1, 3)]),
              jnp.concatenate([wo, wo_c.reshape(-1, 3)]))
    mapped = tonemap(radiance(f[:n], wi, jnp), exposure[:, None], jnp)
    d = jnp.where(scored[:, None] > 0, mapped - ref, 0.0)
    return jnp.sum(d * d), jnp.all(jnp.isfinite(d)), f[n:].reshape(wi_c.shape)


def sphere_psnr(table: MerlTable, model: AbstractBRDFModel, params: dict, size: int = 128) -> float:
    """PSNR (dB) of the model's sphere renders against the table's own."""
    return SphereReference(table, size).psnr(model, params)


def sphere_colour_error(table: MerlTable, model: AbstractBRDFModel, params: dict,
                        size: int = COLOUR_SIZE) -> list[float]:
    """Per channel, the relative error of the model's mean radiance over the lit,
    measured pixels of the key-light sphere against the table's (R, G, B; 0.1 is 10%
    too bright): the colour a viewer sees of the material as a whole. A channel the
    table leaves black (mean below 1e-9) is reported as 0 when the model's is too, and
    as None otherwise."""
    light = LIGHTS[0][1]
    ref, lit = render_table(table, light, size)
    img, _ = render_model(model, params, light, size)
    return _colour_error(img, lit, ref)


def _colour_error(img: np.ndarray, lit: np.ndarray, ref: np.ndarray) -> list:
    """:func:`sphere_colour_error` from the model's render ``img`` (as
    :func:`render_model` makes it) and the table's ``ref`` of the same sphere."""
    ok = lit & np.all(np.isfinite(ref), axis=-1)
    if not ok.any():
        return [None, None, None]
    a, b = img[ok].mean(axis=0), ref[ok].mean(axis=0)
    return [float(x / y - 1.0) if y > 1e-9 else (0.0 if abs(x) <= 1e-9 else None)
            for x, y in zip(a, b, strict=True)]
