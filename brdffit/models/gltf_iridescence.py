"""glTF 2.0 metallic-roughness with a thin film (``KHR_materials_iridescence``), as the
extension's text defines it.

``gltf_iridescence``: the core material (``gltf_pbr``, Appendix B) under a thin
dielectric film whose interference tints the specular reflection with a hue that turns
with the angle (soap bubbles, oil films, pearlescent and colour-changing paints). The
extension replaces the core's two BRDFs ("Iridescence BRDF", "Implementation Notes"):

    metal      = mix(specular F_m,  specular F_film(base_color),  iridescence)
    dielectric = mix(fresnel_mix(1.5, diffuse, specular),
                     rgb_mix(diffuse, specular, F_film(0.04)),    iridescence)
    rgb_mix    = (1 - max(F_film)) diffuse + F_film specular
    f          = mix(dielectric, metal, metallic)

with ``specular`` the white lobe D V of ``gltf_pbr``, ``diffuse = base_color / pi``
and ``F_film(base_f0)`` the film's Fresnel (:func:`film_fresnel`): Belcour and Barla's
two-interface Airy model as the extension writes it (Schlick at each interface, phase
shifts of 0 or pi, the first two orders of the spectral integral against Gaussian fits
of the XYZ matching functions, XYZ to linear Rec. 709, negative values clamped). The
film is lit at "the viewing angle theta_1", the view's angle to the normal (``n.v``,
``cos_o``), as the extension's reference implementation (Khronos's sample viewer),
three.js and Filament evaluate it, once per pixel: the viewers people open show the
fitted film. (At the view's angle to the half vector, ``v.h``, as the core's Fresnel
reads it, the model would be reciprocal, and three.js's render of the same file was
19% off at the median pixel: tests/test_export_viewers.py.) So, as the clear coat's
Fresnel (``gltf_clearcoat``), the film reads the view alone, and the model is not
reciprocal. Where the text leaves a choice:

- the base's index from its f0 is taken at ``min(f0 + 1e-4, 0.9999)``: the text adds
  1e-4 "to guard against 1.0", which at a base colour of 1 still makes the index
  negative; three.js clamps to 0.9999, and the two agree below 0.9998;
- the thickness is ``iridescenceThicknessMaximum``: without a thickness texture the
  extension reads the film as that thickness everywhere.

What three.js r187 shows differs in the rest of its shading: ``gltf_threejs_iridescence``
is the same file as three.js shades it (its base, ``gltf_threejs``; its Schlick's exp2
form at each interface of the film; the film replacing the specular Fresnel alone, the
diffuse kept as the base leaves it).

At ``iridescence = 0`` the material is ``gltf_pbr``'s exactly: a fit starts from the
``gltf_pbr`` fit with the film off (``parent``), and from that base under each film of a
coarse scan of thickness and index (the film's colour is many-moded in its thickness),
so it never ends worse than its base.

| name                  | range          | meaning                                         |
|-----------------------|----------------|-------------------------------------------------|
| base_color            | [0, 1], RGB    | ``baseColorFactor`` (linear RGB)                |
| metallic              | [0, 1]         | ``metallicFactor``                              |
| roughness             | [0.0316, 1] (log) | ``roughnessFactor``                          |
| iridescence           | [0, 1]         | ``iridescenceFactor``: the film's weight        |
| iridescence_ior       | [1.2, 2.5]     | ``iridescenceIor``: the film's index            |
| iridescence_thickness | [30, 1200] nm  | ``iridescenceThicknessMaximum`` (and Minimum)   |
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .base import Params, ParamSpec
from .computed_once import computed_once
from .frame import Frame
from .gltf_layer import BASE, THREEJS_BASE, GltfLayer
from .gltf_pbr import BASE_COLOR, DIELECTRIC_F0, METALLIC, ROUGHNESS
from .gltf_threejs import threejs_fresnel
from .guarded import safe_sqrt

IRIDESCENCE = ParamSpec("iridescence", "iridescenceFactor: the thin film's weight", 0.0, 1.0)
#: Films of real coatings: from ~1.3 (the extension's default; fluorides, oxides of
#: silicon) to ~2.5 (titanium dioxide, the pigment of pearlescent flakes).
IRIDESCENCE_IOR = ParamSpec("iridescence_ior", "iridescenceIor: the film's index of refraction",
                            1.2, 2.5)
#: Below ~30 nm a film adds no hue (its optical path is far under visible wavelengths);
#: above ~1200 nm its colours wash out to pastel (the spectral integral's Gaussians
#: damp both orders at optical paths beyond ~3 um).
IRIDESCENCE_THICKNESS = ParamSpec(
    "iridescence_thickness", "iridescenceThicknessMaximum: the film's thickness, nm",
    30.0, 1200.0)

#: The films a fit starts from. The film's hue turns through a cycle per ~590 nm of
#: optical path 2 n d (the matching functions' Fourier position, 1.7e6 /m), and a
#: start finds the optimum of its own sixth of a cycle or so: on a dark dielectric
#: under a film of index 2.0, 650 nm thick, a start at 600 nm (200 nm of path away)
#: ended elsewhere at log_rmse 0.008. So the scan steps the path by 100 nm, from 100
#: nm to the thickest film's, at a low and a high index (the index also sets how
#: strongly the film reflects).
IOR_STARTS = (1.4, 2.0)
PATH_STEP = 100.0
FILM_START = 0.5


def _film_scan() -> tuple[dict, ...]:
    lo, hi = IRIDESCENCE_THICKNESS.lower, IRIDESCENCE_THICKNESS.upper
    films = []
    for n in IOR_STARTS:
        for path in np.arange(PATH_STEP, 2 * n * hi + 1, PATH_STEP):
            d = float(np.clip(path / (2 * n), lo, hi))
            films.append({"iridescence": FILM_START, "iridescence_ior": n,
                          "iridescence_thickness": d})
    return tuple(films)


# The extension's fit of the XYZ matching functions in Fourier space (Belcour and Barla
# 2017, as the extension's "Analytic Spectral Integration" writes them): per X, Y, Z
# an amplitude, a position and a variance, X with a second lobe, and their scale.
_VAL = np.array([5.4856e-13, 4.4201e-13, 5.2481e-13])
_POS = np.array([1.6810e06, 1.7953e06, 2.2084e06])
_VAR = np.array([4.3278e09, 9.3046e09, 6.6121e09])
_X2 = (9.7470e-14, 2.2399e06, 4.5282e09)
_XYZ_SCALE = 1.0685e-7
#: XYZ to linear Rec. 709 (rows: R, G, B).
XYZ_TO_REC709 = np.array([[3.2404542, -1.5371385, -0.4985314],
                          [-0.9692660, 1.8760108, 0.0415560],
                          [0.0556434, -0.2040259, 1.0572252]])
#: The guards of the extension's text: the base's f0 below 1, the compound reflectance
#: of the two interfaces within [1e-5, 0.9999].
_F0_GUARD, _F0_MAX = 1e-4, 0.9999
_R123_RANGE = (1e-5, 0.9999)


def _schlick(f0, cos):
    return f0 + (1.0 - f0) * (1.0 - cos) ** 5


#: three.js's film (``evalIridescence``): its Schlick, the base's f0 clamped, not guarded.
THREEJS_FILM = {"schlick": threejs_fresnel, "f0_guard": 0.0}


class Film(NamedTuple):
    """What a film's Fresnel shares between every base under it (the dielectric's f0
    and the metal's base colour): Snell's cosine in the film, the first interface's
    reflectance, and the two orders of the spectral integral without their phase
    shifts (:func:`film_interference`)."""

    cos2: object
    r12: object
    orders: tuple  # ((3, ...) XYZ of order 1, of order 2), unshifted


def _sensitivity_orders(opd, cos1):
    """``evalSensitivity`` of an optical path difference ``opd`` (nm, (...)) at orders 1
    and 2 (``evalSensitivity(m * opd, m * shift)``), each (3, ...) XYZ, before the phase
    shift and the matrix to Rec. 709; ``cos1``: the light's cosines (data).

    A base's shift is 0 or pi per component at order 1 (pi or 2 pi at order 2, where the
    cosine is the same), so it is a sign (:func:`film_fresnel`), and order 2 is order
    1's cosine and Gaussian at twice the phase: ``cos(2x) = 2 cos(x)^2 - 1``,
    ``exp(-4a) = exp(-a)^4``. The extension's text takes each order of each base's film
    apart, 16 cosines a sample where these are 4 (kept: ``computed_once``): a
    solver step's normal equations on 16,384 samples cost 13.6 ms where they cost 24.2
    (gltf_pbr's: 1.3), and a film's fit ~35% less. The text itself, line by line, is
    ``brdffit.export.validate``'s; the two agree to 1e-9 (tests/test_layered_models.py)."""
    expand = (slice(None),) + (None,) * opd.ndim
    phase = 2.0 * jnp.pi * opd * 1e-9
    val, pos, var = (jnp.asarray(a)[expand] for a in (_VAL, _POS, _VAR))
    a, p, v = _X2
    amplitude = val * jnp.sqrt(2.0 * jnp.pi * var) / _XYZ_SCALE
    amplitude2 = a * np.sqrt(2.0 * np.pi * v) / _XYZ_SCALE

    def waves(phase):  # X, Y, Z's cosines and Gaussians, and X's second lobe's
        return (jnp.cos(pos * phase), jnp.exp(-(phase * phase) * var), jnp.cos(p * phase),
                jnp.exp(-v * phase * phase))

    c1, g1, c1_x2, g1_x2 = computed_once(waves, phase, cos1)
    c2, c2_x2 = 2.0 * c1 * c1 - 1.0, 2.0 * c1_x2 * c1_x2 - 1.0
    g2, g2_x2 = (g1 * g1) ** 2, (g1_x2 * g1_x2) ** 2
    first, second = amplitude * c1 * g1, amplitude * c2 * g2
    first = jnp.stack([first[0] + amplitude2 * c1_x2 * g1_x2, first[1], first[2]])
    second = jnp.stack([second[0] + amplitude2 * c2_x2 * g2_x2, second[1], second[2]])
    return first, second


def film_interference(film_ior, thickness, cos1, schlick=_schlick) -> Film:
    """The part of a film's Fresnel that its base does not change: a film of index
    ``film_ior`` and ``thickness`` nm in air, lit at ``cos1`` (...) to the
    (micro)surface's normal."""
    # Snell into the film; the film is denser than air, so no total internal reflection
    cos2 = jnp.sqrt(jnp.maximum(1.0 - (1.0 - cos1 * cos1) / (film_ior * film_ior), 1e-12))
    # the first interface (air to film), Schlick's
    r12 = schlick(((film_ior - 1.0) / (film_ior + 1.0)) ** 2, cos1)
    return Film(cos2, r12, _sensitivity_orders(2.0 * film_ior * thickness * cos2, cos1))


def film_fresnel(film_ior, thickness, base_f0, cos1, schlick=_schlick, f0_guard=_F0_GUARD,
                 film: Film | None = None):
    """The thin film's Fresnel (3, ...) (``iridescent_fresnel``): a film of index
    ``film_ior`` and ``thickness`` nm in air over a base of reflectance ``base_f0``
    ((3, ...) or a scalar), lit at ``cos1`` (...) to the (micro)surface's normal.
    ``schlick`` computes ``f0 + (1 - f0) (1 - cos)^5`` at each interface and
    ``f0_guard`` is added to the base's f0 before its index is taken: the extension's
    text by default; three.js's ``evalIridescence`` takes its exp2 form and no guard
    (:data:`THREEJS_FILM`). ``film``: :func:`film_interference` of the same film, light
    and ``schlick``, computed once for several bases."""
    film = film_interference(film_ior, thickness, cos1, schlick) if film is None else film
    base_f0 = jnp.broadcast_to(base_f0, (3,) + cos1.shape) if jnp.ndim(base_f0) == 0 \
        else base_f0
    r12 = film.r12
    t121 = 1.0 - r12
    # three.js's film has no guard: a black base's f0 of 0 takes safe_sqrt's finite
    # gradient (the same value)
    sqrt_f0 = safe_sqrt(jnp.minimum(base_f0 + f0_guard, _F0_MAX))
    base_ior = (1.0 + sqrt_f0) / (1.0 - sqrt_f0)
    # the second interface (film to base), Schlick's
    r23 = schlick(((base_ior - film_ior) / (base_ior + film_ior)) ** 2, film.cos2[None])
    # A reflection off a denser medium shifts the phase by pi: air to film always
    # (phi21 = pi), film to base where the base's index is the lower. The text's
    # cos(m opd_phase + m phi) per XYZ component: at order 1 a shift of 2 pi (base the
    # lower) keeps the cosine and pi negates it; at order 2 both keep it.
    sign1 = jnp.where(base_ior < film_ior, 1.0, -1.0)
    r123 = jnp.clip(r12[None] * r23, *_R123_RANGE)
    rs = t121[None] ** 2 * r23 / (1.0 - r123)
    out = r12[None] + rs
    cm = rs - t121[None]
    sqrt_r123 = jnp.sqrt(r123)
    for xyz in (film.orders[0] * sign1, film.orders[1]):
        cm = cm * sqrt_r123
        out = out + cm * 2.0 * jnp.tensordot(jnp.asarray(XYZ_TO_REC709), xyz, axes=1)
    return jnp.maximum(out, 0.0)


class GltfIridescence(GltfLayer):
    name = "gltf_iridescence"
    param_specs = (BASE_COLOR, METALLIC, ROUGHNESS, IRIDESCENCE, IRIDESCENCE_IOR,
                   IRIDESCENCE_THICKNESS)
    layer_params = {"iridescence": ("iridescence", ("iridescence_ior", "iridescence_thickness"))}
    holds_absent_layers = True  # an absent film's thickness and index: 4 x 256 steps
    #: a half-weight film at each optical path of the scan, at each index
    layer_starts = _film_scan()
    #: the scan over the base's own fit too: a film's hue is many-moded in its
    #: thickness, and from the base's fit with the film off no gradient finds it
    parent_scan = layer_starts

    #: one start ended in another cycle of the film's hue on a dark, weakly metallic
    #: table (log_rmse 4.7x the truth's); four found it (tests/test_layered_models.py)
    least_starts = 4

    def embed_parent(self, parent_params: dict) -> dict:
        """The ``gltf_pbr`` fit with the film off (iridescence 0), ready to grow."""
        return {**parent_params, "iridescence": 0.0, "iridescence_ior": 1.4,
                "iridescence_thickness": 400.0}

    def eval_channels(self, params: Params, frame: Frame):
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        terms = BASE._terms(params, frame)
        base = BASE.mixed_channels(params, terms)
        _, m, dg, _ = terms
        colour = params["base_color"][expand]
        ior, d = params["iridescence_ior"], params["iridescence_thickness"]
        # the film at the view's angle to the normal (module docstring)
        cos_v = jnp.clip(frame.cos_o, 0.0, 1.0)
        film = film_interference(ior, d, cos_v)  # shared by both bases under it
        film_d = film_fresnel(ior, d, DIELECTRIC_F0, cos_v, film=film)
        film_m = film_fresnel(ior, d, colour * jnp.ones_like(cos_v)[None], cos_v, film=film)
        dielectric = (1.0 - jnp.max(film_d, axis=0))[None] * colour / jnp.pi + film_d * dg
        filmed = (1.0 - m) * dielectric + m * film_m * dg
        weight = params["iridescence"]
        return (1.0 - weight) * base + weight * filmed


class GltfThreejsIridescence(GltfIridescence):
    """A ``KHR_materials_iridescence`` file as three.js r187 shades it for a direct light
    (``evalIridescence`` in ``lights_fragment_begin``, ``BRDF_GGX``,
    ``RE_Direct_Physical``), the same six parameters:

        F_film   = mix(film(0.04), film(base_color), metallic)    at n.v, once per pixel
        f        = mix(F, F_film, iridescence) D V compensation + diffuse

    with F, D, V, the compensation and the diffuse three.js's shading of the core
    factors (``gltf_threejs``), and the film three.js's: the extension's Airy model with
    its exp2 Schlick at each interface and the base's f0 clamped to 0.9999, not guarded
    (:data:`THREEJS_FILM`). The spec (``gltf_iridescence``) also takes the film into the
    dielectric's diffuse (``1 - max(F_film)``); three.js leaves the diffuse under the
    base's own Fresnel, and its multiple-scattering compensation untinted by the film.
    What a film export's ``fidelity.viewers["threejs"]`` is measured with
    (tests/test_export_viewers.py checks it against three.js's render of the file). Its
    fit starts from ``gltf_threejs``'s with the film off, as ``gltf_iridescence``'s from
    ``gltf_pbr``'s."""

    name = "gltf_threejs_iridescence"
    parent = "gltf_threejs"
    base_model = THREEJS_BASE

    def eval_channels(self, params: Params, frame: Frame):
        expand = (slice(None),) + (None,) * frame.cos_i.ndim
        fresnel, lobe, compensation, diffuse = self.base_model.shading_terms(params, frame)
        m = params["metallic"]
        ior, d = params["iridescence_ior"], params["iridescence_thickness"]
        cos_v = jnp.clip(frame.cos_o, 0.0, 1.0)
        colour = params["base_color"][expand] * jnp.ones_like(cos_v)[None]
        def films(a):  # the film mixed for the metalness, as three.js shades it
            ior, d, colour, m, cos_v = a
            shared = film_interference(ior, d, cos_v, THREEJS_FILM["schlick"])
            return ((1.0 - m) * film_fresnel(ior, d, DIELECTRIC_F0, cos_v, **THREEJS_FILM,
                                             film=shared)
                    + m * film_fresnel(ior, d, colour, cos_v, **THREEJS_FILM, film=shared))

        # computed once and stored, as its cosines are (computed_once): 30 -> 15 ms a
        # solver step's normal equations on 16,384 samples
        film = computed_once(films, (ior, d, colour, m, cos_v), cos_v)
        weight = params["iridescence"]
        specular = ((1.0 - weight) * fresnel + weight * film) * lobe * compensation
        return specular + diffuse
