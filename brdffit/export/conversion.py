"""A fit as a renderer's own model: copied where it is one, refitted where it is not.

Each export target shades with one formula that brdffit also implements as a model
(``gltf_pbr`` for glTF and MaterialX, ``rough_conductor`` for Mitsuba 3; see
docs/models.md). A fit of that model converts exactly: its parameters are the
material's. Any other fit is converted by fitting the target model to the fitted
BRDF itself, evaluated at every bin centre above the horizon (a noiseless table of
the fit): the least-squares optimum of the same loss a fit minimises, so the
conversion loses as little as that model allows, and its ``log_rmse`` against the
fit *is* the fidelity lost. That number is reported with every approximate export.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from brdffit import models, runtime
from brdffit.errors import ExportError
from brdffit.fitting.result import FitResult
from brdffit.io.grid import bin_grid
from brdffit.io.merl import MAX_VALUE, MIN_PEAK, MerlTable

#: Bins the conversion's refit samples (the reported loss is on every bin).
CONVERSION_SAMPLES = 16384
#: A parameter this close (relative to its range) to a bound is reported as at it.
_AT_BOUND = 1e-4


@dataclass
class Conversion:
    """The target model's parameters for a fit, and what the conversion cost."""

    target_model: str
    params: dict
    exact: bool
    #: log_rmse (brdffit.fitting.loss) of the target's parameters against the fitted
    #: BRDF, on every bin above the horizon; 0 for an exact conversion.
    log_rmse_to_fit: float
    warnings: list[str] = field(default_factory=list)

    def fidelity(self, result: FitResult) -> dict:
        return {
            "exact": self.exact,
            "target_model": self.target_model,
            "log_rmse_to_fit": self.log_rmse_to_fit,
            "fit_log_rmse": result.error.get("log_rmse"),
        }


@runtime.in_float64
def fit_as_table(result: FitResult) -> MerlTable:
    """The fitted BRDF at every bin centre above the horizon, as a table."""
    import jax.numpy as jnp

    model = models.get(result.model)
    params = {k: jnp.asarray(v) for k, v in model.check_params(result.params).items()}
    g = bin_grid()
    idx = np.flatnonzero(g.above_horizon)
    values = np.zeros((3, g.weight.size))
    values[:, idx] = np.asarray(model(params, jnp.asarray(g.wi[idx]), jnp.asarray(g.wo[idx]))).T
    # a fit outside what any table holds has nothing a renderer could show: said of the
    # fit, not in the words of a corrupt file's refusal
    peak = float(np.max(values, initial=0.0)) if np.all(np.isfinite(values)) else np.inf
    if not peak >= MIN_PEAK:
        raise ExportError(f"the {result.model} fit is black (its brightest value is "
                          f"{peak:.3g} 1/sr, below {MIN_PEAK:g}): nothing to export")
    if peak > MAX_VALUE:
        raise ExportError(f"the {result.model} fit reaches {peak:.3g} 1/sr (measured BRDFs "
                          f"peak near 1e4, at most {MAX_VALUE:g}): its parameters are no "
                          "material a renderer could show")
    return MerlTable.from_values(values, g.above_horizon, source=f"<{result.model} fit>")


#: A blend's conductor that reflects less than this at normal incidence (its brightest
#: channel) is no metal: a dielectric reflects 2-5% there, any metal ~50% or more. A
#: refit of a pure diffuse fit (lambert, oren_nayar, a ggx whose lobe went to 0) makes
#: one: eta ~1, k ~0, which the blend carries at no cost to its shading.
BLACK_CONDUCTOR = 0.01


def _black_conductor(p: dict) -> bool:
    """Whether a ``rough_conductor`` blend's conductor reflects nothing to speak of
    (:data:`BLACK_CONDUCTOR`), or has no weight in the blend."""
    from brdffit.models.renderer_terms import conductor_fresnel

    f0 = conductor_fresnel(np.asarray(p["eta"], float), np.asarray(p["k"], float), 1.0)
    return float(np.max(f0)) < BLACK_CONDUCTOR or float(p["weight"]) >= 1.0


def _reflecting_metal(p: dict) -> float:
    """The metal fraction of a ``rough_conductor`` blend: its conductor's weight,
    where the conductor reflects; 0 where it is black."""
    return 0.0 if _black_conductor(p) else 1.0 - float(p["weight"])


class _UnseenPart(NamedTuple):
    """A part of a target model that can be black (``when(params)``): its ``params``
    then shape nothing, no bound of theirs is a clamp worth a warning, and one line
    (``why``) says so instead."""

    when: Callable[[dict], bool]
    params: tuple[str, ...]
    why: str


_UNSEEN_PARTS = {"rough_conductor": _UnseenPart(
    _black_conductor, ("eta", "k", "alpha"),
    f"the blend's conductor reflects nothing (under {BLACK_CONDUCTOR:.0%} at normal "
    "incidence, or weight 1): a diffuse material, whose eta, k and alpha shape nothing")}


#: A layer's weight below this shades nothing a table shows.
_NIL_WEIGHT = 1e-3
#: A layer's weight -> the parameters that shape nothing while it is nil.
_LAYER_SHAPES = {"specular": ("specular_color", "specular_roughness"),
                 "coat": ("coat_roughness",), "clearcoat": ("clearcoat_roughness",
                                                           "clearcoat_gloss"),
                 "sheen": ("sheen_color", "sheen_roughness", "sheen_tint"),
                 "sheen_color": ("sheen_roughness",),
                 "iridescence": ("iridescence_ior", "iridescence_thickness")}


def _shaping_nothing(params: dict) -> set[str]:
    """Parameters of a layer that reflects nothing (its weight nil; MaterialX's specular
    at an index of 1, F0 0), whose value no data decided: at a bound of their range they
    are no clamp (a lambert fit's MaterialX refit ended at specular_IOR 1 and
    specular_color 1, and was told the colour was clamped)."""
    out: set[str] = set()
    for weight, shaped in _LAYER_SHAPES.items():
        if weight in params and np.max(np.asarray(params[weight], float)) < _NIL_WEIGHT:
            out.update(shaped)
    if "specular_IOR" in params and float(params["specular_IOR"]) < 1.0 + _NIL_WEIGHT:
        out.update(_LAYER_SHAPES["specular"])
    return out


def bound_warnings(target_model: str, params: dict, fitted: bool = False) -> list[str]:
    """One line per parameter with a value at the bound of the target's range (its
    channels named together): there the renderer's range, not the data, decided the
    value. Each says what to do next; ``fitted``: the params are a fit of the target
    model itself (an exact export), whose error already is what the range costs."""
    out, unseen = [], ()
    part = _UNSEEN_PARTS.get(target_model)
    if part is not None and part.when(params):
        out, unseen = [f"diffuse: {part.why}"], part.params
    unseen = {*unseen, *_shaping_nothing(params)}
    for spec in models.get(target_model).param_specs:
        if spec.name in unseen:
            continue
        v = np.atleast_1d(np.asarray(params[spec.name], float))
        hi = spec.upper if spec.upper is not None else np.inf
        span = (hi - spec.lower) if np.isfinite(hi) else max(1.0, abs(spec.lower))
        low, high = [], []
        for c, x in zip("RGB" if spec.rgb else " ", v, strict=True):
            shown = f"{c} {x:.6g}" if spec.rgb else f"{x:.6g}"
            if x <= spec.lower + _AT_BOUND * span and spec.lower > 0 \
                    and spec.name not in _NO_REFLECTION_LOWER:
                low.append(shown)
            elif np.isfinite(hi) and x >= hi - _AT_BOUND * span and spec.name in _CLAMP_UPPER:
                high.append(shown)
        if low:
            out.append(f"clamp: {spec.name} = {', '.join(low)} is at the lower bound "
                       f"{spec.lower:g} of {target_model}; next: "
                       f"{_clamp_next(target_model, fitted)}")
        if high:
            out.append(f"clamp: {spec.name} = {', '.join(high)} is at the upper bound {hi:g} "
                       f"of {target_model}: the fit would want more; next: "
                       f"{_clamp_next(target_model, fitted)}")
    return out


def _clamp_next(target_model: str, fitted: bool) -> str:
    if fitted:  # told to fit what it already is, a user asked what to do (issue review)
        return (f"nothing within {target_model}: this fit of it ended there, so its error "
                "is what the renderer's range costs; a model with a wider range (`brdffit "
                "models`) may fit the table better, in another renderer")
    return (f"fit {target_model} to the table itself (brdffit fit TABLE --model "
            f"{target_model}): its error is what the renderer's range costs")


#: Parameters whose upper bound is a limit the data can push against (a metallic of 1
#: or a weight of 1 is a legitimate material, not a clamp): principled's ``specular``
#: of 1 is its F0 0.08, its ``clearcoat_gloss`` of 1 the sharpest coat it has, and
#: MaterialX's ``specular_IOR`` stops at 50 (a refit of two-layer-gold's coat ended at
#: specular 0.99999998 and clearcoat_gloss 0.99999999, and said nothing). The layers'
#: tints and roughnesses too (red-plastic's sheen left glTF at sheenRoughnessFactor
#: 0.99999975, a coat MaterialX at coat_roughness 0.99999962, unsaid), a tint, a
#: specular colour or scale at 1 wanting more light than the range has, a film's
#: thickness and index at the range's end. Not the weights (a metallic, a coat, a
#: sheen's or a film's weight, principled's sheen_tint): 1 is a material.
_CLAMP_UPPER = {"base_color", "kd", "ks", "eta", "k", "roughness", "alpha", "specular",
                "clearcoat_gloss", "specular_IOR", "ior", "exponent", "color0", "color90",
                "specular_color", "specular_roughness", "coat_roughness",
                "clearcoat_roughness", "sheen_color", "sheen_roughness",
                "iridescence_ior", "iridescence_thickness"}
#: Indices whose lower bound 1 is a surface that reflects nothing (F0 = 0, as a ggx
#: ``f0`` of 0, which is not flagged either): a material the data can ask for, a matte
#: one, not a value the renderer's range imposed (a lambert fit's MaterialX refit ends
#: at specular_IOR 1 and was told it was clamped there).
_NO_REFLECTION_LOWER = {"specular_IOR", "ior"}


def convert(result: FitResult, target_models: tuple[str, ...], *,
            samples: int = CONVERSION_SAMPLES, seed: int = 0,
            measured: MerlTable | None = None) -> Conversion:
    """``result`` as parameters of one of ``target_models``, the models the renderer
    shades exactly: a copy when the fit is one of them, else a refit of the first
    (see the module docstring). ``measured``: refit the first to this measured table
    instead, with the fit's loss (an export for one viewer's shading: the optimum of
    what that viewer shows, not the nearest point to another model's fit); the fit's
    own model is then refitted too."""
    from brdffit.fitting.pipeline import fit
    from brdffit.fitting.problem import table_error

    if measured is not None:
        target_model = target_models[0]
        refit = fit(measured, target_model, samples=samples, seed=seed, loss=result.loss)
        to_fit = table_error(fit_as_table(result), target_model, refit.params)["log_rmse"]
        warnings = [f"refitted: {target_model} (the viewer's shading) fitted to the measured "
                    f"table with the {result.loss} loss; its log_rmse to the {result.model} "
                    f"fit {to_fit:.4g}"]
        if not refit.converged:
            warnings.append(f"the viewer's {target_model} fit ended {refit.result}")
        return Conversion(target_model, refit.params, False, float(to_fit),
                          warnings + bound_warnings(target_model, refit.params))

    warnings = []
    if not result.converged:
        warnings.append(f"the {result.model} fit did not converge ({result.result}): the "
                        "export carries its last point")
    if result.model in target_models:
        params = models.get(result.model).check_params(result.params)
        plain = {k: np.asarray(v).tolist() for k, v in params.items()}
        return Conversion(result.model, plain, True, 0.0,
                          warnings + bound_warnings(result.model, plain, fitted=True))
    target_model = target_models[0]
    # the fit's own loss: a render-loss fit refitted under the log loss left glTF 17 dB
    # below the fit's picture (nickel's rough_conductor: 14.1 against 31.8 dB)
    refit = fit(fit_as_table(result), target_model, samples=samples, seed=seed,
                loss=result.loss)
    own = result.error.get("log_rmse", np.nan)  # NaN where the fit could not measure it
    warnings.append(
        f"approximated: {target_model} (the renderer's model) fitted to the {result.model} "
        f"fit at every bin above the horizon"
        f"{'' if result.loss == 'log' else f' with the {result.loss} loss'}; log_rmse to the fit "
        f"{refit.error['log_rmse']:.4g} (the fit's own log_rmse to its table: "
        f"{format(own, '.4g') if np.isfinite(own) else 'not measured'})")
    if not refit.converged:
        warnings.append(f"the conversion's {target_model} fit ended {refit.result}")
    return Conversion(target_model, refit.params, False, float(refit.error["log_rmse"]),
                      warnings + bound_warnings(target_model, refit.params))


@dataclass(frozen=True)
class Dielectric:
    """One dielectric a metal mixture is weighed against: the model fitted, and its
    parameters as the exported model's (``export_model``)."""

    model: str
    export_model: str
    as_export: Callable[[dict], dict] = dict


@dataclass(frozen=True)
class ClassAlternative:
    """How a target's metal mixture is weighed against its dielectrics (the best of
    them, by their error to the table): the mixture's metal fraction."""

    mixture_model: str
    dielectrics: tuple[Dielectric, ...]
    metal_fraction: Callable[[dict], float]


#: target model of a refit -> its dielectric alternatives: glTF metallic 0, MaterialX
#: metalness 0, and for Mitsuba its roughplastic or its principled (a sheen: fabrics)
#: in place of the roughconductor blend.
CLASS_ALTERNATIVES = {
    "gltf_pbr": ClassAlternative(
        "gltf_pbr", (Dielectric("gltf_pbr_dielectric", "gltf_pbr",
                                lambda p: {**p, "metallic": 0.0}),),
        lambda p: float(p["metallic"])),
    "standard_surface": ClassAlternative(
        "standard_surface", (Dielectric("standard_surface_dielectric", "standard_surface",
                                        lambda p: {**p, "metalness": 0.0}),),
        lambda p: float(p["metalness"])),
    "rough_conductor": ClassAlternative(
        "rough_conductor", (Dielectric("rough_plastic", "rough_plastic"),
                            Dielectric("principled", "principled")),
        _reflecting_metal),
}
#: A metal mixture whose metal fraction is above this is weighed against a dielectric.
MIXTURE_METALLIC = 0.05
#: The dielectric is exported where its error to the table is at most this times the
#: metal mixture's (issue 42: a plastic or a fabric exported as 95% metal looks
#: plausible to nobody, and costs a renderer's user the material's class).
DIELECTRIC_TOLERANCE = 1.1
#: ... or within DIELECTRIC_WITH_BODY where the table has a diffuse body at least this
#: bright (the mean of its diffuse estimate, ``brdffit.fitting.starts``): metals have
#: none. On the real materials: plastics, paints and fabrics 0.11-0.28; metallic
#: paints and metals 0.001-0.03. Beyond it the mixture's fit is kept: its Fresnel
#: says metal more plainly than the body says dielectric (a bright, coloured, f0 0.6
#: lobe over a diffuse base: 3x the dielectric's error). A felt's sheen costs glTF's
#: dielectric 1.23x (pink-felt), which the warning says; Mitsuba's principled has a
#: sheen (0.84x the conductor blend's error there).
DIFFUSE_BODY = 0.1
DIELECTRIC_WITH_BODY = 1.5


#: The renderers' names of the metal fraction of their base (glTF's and Mitsuba's
#: principled metallic, MaterialX's metalness).
METAL_FRACTION = ("metallic", "metalness")


def half_metal_said(conv: Conversion) -> Conversion:
    """A material whose metal fraction is neither a metal's nor a dielectric's keeps it
    and says so, where it was not weighed against a dielectric (:func:`dielectric_or_mixture`
    weighs a refit of a base model for the spec): an exact copy (a fabric's gltf_sheen
    fit at metallic 0.44), the fit being the user's choice of class; a layered model's
    refit, a viewer's, one asked for by ``target_model`` (metallic 0.28-0.51, exported
    without a word). Renderers mean such values for the seam between a metal and a
    dielectric, where a measured material is one."""
    name, value = next(((k, conv.params[k]) for k in METAL_FRACTION if k in conv.params),
                       (None, None))
    if value is None:
        return conv
    m = float(np.mean(value))
    if not MIXTURE_METALLIC < m < 1.0 - MIXTURE_METALLIC:
        return conv
    how = ("as fitted (an exact copy of the fit)" if conv.exact else
           f"as the {conv.target_model} refit came out (not weighed against a dielectric: "
           "the export of a base model for the spec is)")
    conv.warnings.append(
        f"class: {m:.3g} metal, {how}: neither a metal nor a dielectric, which renderers "
        "mean for the seam between the two; a measured plastic or fabric is a dielectric "
        f"(fit a dielectric model to the table, e.g. brdffit fit TABLE --model "
        f"{_dielectric_to_fit(name)}, whose export has {name} 0)")
    return conv


def _dielectric_to_fit(metal_fraction: str) -> str:
    """The dielectric model :data:`CLASS_ALTERNATIVES` weighs against the base model whose
    metal fraction is named ``metal_fraction`` (gltf_pbr's ``metallic``:
    gltf_pbr_dielectric), for a half-metal's advice."""
    return next(alt.dielectrics[0].model for alt in CLASS_ALTERNATIVES.values()
                if metal_fraction in {s.name for s in models.get(alt.mixture_model).param_specs})


def dielectric_or_mixture(result: FitResult, conv: Conversion,
                          measured: MerlTable | None) -> tuple[Conversion, dict | None]:
    """For a refit that came out a metal mixture (glTF's ``gltf_pbr`` with metallic,
    MaterialX's ``standard_surface`` with metalness, Mitsuba's ``rough_conductor`` blend
    with a conductor weight above :data:`MIXTURE_METALLIC`; an exact fit of one is
    copied as it is): the dielectric alternative (:data:`CLASS_ALTERNATIVES`) refitted
    to the measured table (else to the fit).
    The dielectric is exported where the evidence says dielectric: its log_rmse there
    is within :data:`DIELECTRIC_TOLERANCE` of the mixture's, or within
    :data:`DIELECTRIC_WITH_BODY` where the table has a diffuse body
    (:data:`DIFFUSE_BODY`), which no metal has; the other's error is
    reported beside it, and a warning says where the dielectric costs more than the
    tolerance. Returns the conversion to export and the class report
    (``fidelity.material_class``; None where there was no mixture to weigh)."""
    from brdffit.fitting.pipeline import fit
    from brdffit.fitting.problem import table_error
    from brdffit.fitting.sampling import usable_bins
    from brdffit.fitting.starts import table_hints

    alt = CLASS_ALTERNATIVES.get(conv.target_model)
    if conv.exact or alt is None:  # an exact fit is the user's own choice of class
        return half_metal_said(conv), None
    if alt.metal_fraction(conv.params) <= MIXTURE_METALLIC:
        return conv, None
    reference = measured if measured is not None else fit_as_table(result)
    against = "the measured table" if measured is not None else f"the {result.model} fit"
    body = float(np.mean(table_hints(reference, usable_bins(reference).usable).kd))
    tried = []
    fitted_as: dict[str, tuple[str, dict]] = {}  # export model -> the model fitted, its params
    for d in alt.dielectrics:
        fitted = fit(reference, d.model, loss=result.loss).params
        params = d.as_export(fitted)
        tried.append((float(table_error(reference, d.export_model, params)["log_rmse"]),
                      d.export_model, params))
        fitted_as[d.export_model] = (d.model, fitted)
    err_d, export_model, dielectric = min(tried, key=lambda t: t[0])
    err_m = float(table_error(reference, alt.mixture_model, conv.params)["log_rmse"])
    metallic = alt.metal_fraction(conv.params)
    report = {"metallic_of_mixture": metallic, "against": against, "diffuse_body": body,
              "dielectric_model": export_model,
              "dielectrics": {m: e for e, m, _ in tried},
              "dielectric_log_rmse": err_d, "mixture_log_rmse": err_m}
    close = err_d <= DIELECTRIC_TOLERANCE * err_m
    bodied = body >= DIFFUSE_BODY and err_d <= DIELECTRIC_WITH_BODY * err_m
    if not (close or bodied):
        # not "a metal's": a dark fabric's body (red-fabric, 0.07) is under it too
        why = (f"its diffuse body ({body:.3g}) is under the {DIFFUSE_BODY:g} that lets a "
               "dielectric cost more (metals' are 0.001-0.03, plastics' and most fabrics' "
               "0.11-0.28)" if body < DIFFUSE_BODY else
               f"more than {DIELECTRIC_WITH_BODY:g}x even with a diffuse body ({body:.3g})")
        conv.warnings.append(
            f"class: kept the metal mixture (metal fraction {metallic:.3g}): as a dielectric "
            f"({export_model}) its log_rmse to {against} would be {err_d:.4g} against "
            f"{err_m:.4g}, more than {DIELECTRIC_TOLERANCE:g}x, and {why}")
        return conv, {**report, "chosen": "metal mixture"}
    to_fit = (err_d if measured is None
              else float(table_error(fit_as_table(result), export_model, dielectric)["log_rmse"]))
    warnings = [w for w in conv.warnings if not w.startswith(("approximated:", "clamp:"))]
    why = (f"within {DIELECTRIC_TOLERANCE:g}x" if close else
           f"{err_d / err_m:.2f}x, more than {DIELECTRIC_TOLERANCE:g}x: chosen for its diffuse "
           f"body ({body:.3g}), which no metal has; the mixture is the closer fit")
    warnings.append(
        f"class: exported as a dielectric ({export_model}), refitted to {against}: "
        f"log_rmse {err_d:.4g} against {err_m:.4g} for the metal mixture (metal fraction "
        f"{metallic:.3g}), {why}")
    # the bounds the dielectric was fitted within (standard_surface_dielectric's IOR ends
    # at 3, standard_surface's at 50: an IOR of 2.99999997 went out unsaid)
    model_fitted, params_fitted = fitted_as[export_model]
    clamps = bound_warnings(export_model, dielectric)
    said = {w.split(" = ", 1)[0] for w in clamps}
    clamps += [w for w in bound_warnings(model_fitted, params_fitted)
               if w.split(" = ", 1)[0] not in said]
    return (Conversion(export_model, dielectric, False, to_fit, warnings + clamps),
            {**report, "chosen": "dielectric"})
