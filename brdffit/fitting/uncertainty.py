"""How well the data determine each fitted parameter: standard errors, correlations
and a flag for what the table does not pin down.

At the optimum ``theta`` of the weighted least-squares loss (``brdffit.fitting.loss``,
residuals ``r_i = sqrt(w_i) (g(f_model) - g(f_meas))``), with ``J`` the Jacobian of
the residuals with respect to the parameters on the user's scale (kd, ks, alpha,
f0 as docs/models.md has them), the covariance is the sandwich (Huber 1967, White
1980; the HC1 form of MacKinnon & White 1985):

    A = J^T J,   B = sum_i r_i^2 J_i^T J_i,   cov = n / (n - p) A^+ B A^+

``B`` holds the residual variance bin by bin. The plain ``s^2 A^-1`` assumes every
residual has the variance its weight implies; measured noise is multiplicative
(larger on the highlight, in every compressed space), and the sandwich stays right
when that assumption is wrong (``tests/test_uncertainty.py`` checks it against the
spread of fits to 50 noisy copies of a table). The residuals are those of the
solver's own subsample, so the errors are those of the fit that was made.

What the numbers mean: the spread of the fitted values over repeated measurements
with independent noise per bin. On a real table the residual is mostly the model's
misfit, correlated between neighbouring bins; the errors then say how firmly the
data pin each parameter, not a calibrated error bar on the material.

A parameter is **undetermined** when the data do not fix it:

- ``no effect``: the residuals do not change with it (``alpha`` of a table without a
  highlight, where ``ks`` is ~0);
- ``trades off``: it lies along a direction that leaves the loss flat, with the
  parameters named (``ks`` and ``f0`` can do this: the lobe scales with their product);
- ``no lobe``: it shapes a lobe whose scale (``ks``) is within 2 standard errors
  of 0 in every channel (``alpha`` of a diffuse table, where the fit lets a lobe of
  ``ks`` ~0.004 chase the noise); a scale held at a bound above 0 (``ks = 1`` under
  the physical bounds) is a lobe at its limit, not a vanished one;
- ``loose``: its standard error is more than half its scale (its value, or the
  width of its range for ``f0`` and ``sigma``).

A parameter held at a bound by the solver (``f0 = 1``, a dark channel's ``ks = 0``;
``brdffit.fitting.solver``) is reported ``at_bound``; it is left out of the
covariance (held fixed, as the solver holds it) and has no standard error.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from brdffit import executables
from brdffit.fitting.loss import LossData, sandwich_terms
from brdffit.fitting.result import error_measures_nothing
from brdffit.models import AbstractBRDFModel

#: Bins beyond which the Jacobian is taken on every k-th one (its memory is
#: 3 x bins x parameters); the covariance is then scaled by 1/k.
MAX_JACOBIAN_BINS = 65_536
#: An eigenvalue of the scaled A below this fraction of the largest is a flat
#: direction: the loss does not change along it, to float64's resolution.
FLAT = 1e-10
#: Correlation beyond which two parameters are named as trading off.
STRONG_CORRELATION = 0.95
#: A standard error above this fraction of the parameter's scale is "loose".
LOOSE = 0.5
#: The scale parameter(s) of the lobe that each shape parameter shapes: a shape
#: means nothing once its lobe is indistinguishable from zero.
LOBE_SCALE = {"alpha": ("ks",), "n": ("ks",), "f0": ("ks", "ks1", "ks2", "ks3", "ks4"),
              "eta": ("ks",), "alpha1": ("ks1",), "alpha2": ("ks2",), "alpha3": ("ks3",),
              "alpha4": ("ks4",)}  # ggx3's and ggx4's: ggx4's alpha4 beside a ks4 of 1e-12
#                                    read 0.0011111 +- 3.6e-05, determined
#: A lobe is significant when some channel of its scale is this many standard
#: errors above 0.
SIGNIFICANT = 2.0


def entry_names(model: AbstractBRDFModel) -> list[str]:
    """One name per scalar parameter: ``kd[0]``, ``kd[1]``, ``kd[2]``, ``alpha``, ..."""
    out = []
    for s in model.param_specs:
        out += [f"{s.name}[{c}]" for c in range(3)] if s.rgb else [s.name]
    return out


def names_of(model: AbstractBRDFModel) -> set[str]:
    return {s.name for s in model.param_specs}


@executables.jit
def _jacobian_terms(model, u, data: LossData):
    """(A, B, n) of the module docstring, in the unconstrained parameters ``u``.

    Both are sums over the samples, taken as the solver's own normal equations take
    them (``brdffit.fitting.loss.sandwich_terms``: the closed-form Jacobian of a
    colour-linear model, block by block for an every-bin fit); the lm solver's
    float64 solve returns the same terms at its solution, and this program is for
    the other fits. :func:`_on_parameter_scale` moves them to the parameters."""
    a_u, b_u = sandwich_terms(u, model, data)
    return a_u, b_u, 3 * jnp.sum(data.weight > 0)


def _on_parameter_scale(terms, slopes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) in the unconstrained parameters moved to the parameters' own scale: the
    transforms are elementwise, so ``J_theta = J_u diag(1 / slopes)`` with ``slopes =
    d theta / d u`` (:func:`linearisation`). A slope that underflows to 0 (a
    coordinate hundreds of units down a tail: at its bound) leaves its row and
    column at 0, as a parameter without effect."""
    # a diverged fit, or a slope of ~1e-160 (a coordinate far down a tail), overflows
    # here: the caller checks what comes out, and stderr stays clean
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        inverse = np.where(slopes != 0, 1.0 / np.where(slopes != 0, slopes, 1.0), 0.0)
        scale = np.outer(inverse, inverse)
        a, b = (np.asarray(t, np.float64) * scale for t in terms)
    return a, b


@executables.jit
def linearisation(model: AbstractBRDFModel, u):
    """The parameters ``theta`` (flat, in the model's order), which of them sit on a
    bound, and d theta / d u of every entry (the transforms are elementwise): one
    compiled call, not one per eager operation."""
    def flat(v):
        params = model.constrain(v)
        return jnp.concatenate([jnp.ravel(params[s.name]) for s in model.param_specs])

    return flat(u), model.bound_side(u), jnp.diag(jax.jacfwd(flat)(u))


def _scale(model: AbstractBRDFModel, theta: np.ndarray) -> np.ndarray:
    """What "half its scale" is measured against, per entry."""
    out, i = [], 0
    for s in model.param_specs:
        v = theta[i:i + s.size]
        if s.upper is not None and s.scale != "log":
            scale = np.full(s.size, s.upper - s.lower)  # f0, sigma: the range
        else:  # a colour is judged against its brightest channel
            scale = np.full(s.size, max(float(np.max(np.abs(v))), 1e-6))
        out.append(scale)
        i += s.size
    return np.concatenate(out)


def _grouped(model: AbstractBRDFModel, flat) -> dict:
    d, i = {}, 0
    for s in model.param_specs:
        v = [None if x is None else x for x in flat[i:i + s.size]]
        d[s.name] = v if s.rgb else v[0]
        i += s.size
    return d


def parameter_uncertainty(model: AbstractBRDFModel, u: np.ndarray, data: LossData,
                          terms=None) -> dict:
    """The ``uncertainty`` of a :class:`~brdffit.fitting.result.FitResult` (schema in
    docs/results.md) of unconstrained parameters ``u`` on the solver's ``data``.

    ``terms``: (A, B) in the unconstrained parameters at ``u`` on every sample of
    ``data``, where the solver already has them (``brdffit.fitting.problem.
    solve_batch``); only float64 ones are used. Otherwise they are computed here,
    on every k-th sample beyond :data:`MAX_JACOBIAN_BINS`."""
    names = entry_names(model)
    p = len(names)
    theta, bound_side, slopes = (np.asarray(x, np.float64) for x in linearisation(
        model, np.asarray(u, np.float64)))
    if terms is not None and all(np.asarray(t).dtype == np.float64 for t in terms):
        n, k = 3 * int(np.count_nonzero(np.asarray(data.weight) > 0)), 1
    else:
        n_bins = int(data.weight.shape[-1])
        k = max(1, -(-n_bins // MAX_JACOBIAN_BINS))
        if k > 1:
            # a scalar (the loss's selector) has no bins to thin
            data = jax.tree_util.tree_map(lambda a: a[..., ::k] if a.ndim else a, data)
        *terms, n = _jacobian_terms(model, np.asarray(u, np.float64), data)
        n = int(n)
    a, b = _on_parameter_scale(terms, slopes)

    at_bound = bound_side != 0
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        # a fit that ran off the table's scale: no linearisation to report, and no
        # number pretends otherwise (every entry undetermined, no errors)
        a, b = np.zeros_like(a), np.zeros_like(b)
    d = np.sqrt(np.maximum(np.diag(a), 0.0))
    no_effect = ~at_bound & (d <= 1e-12 * max(float(d.max()), 1e-300))
    free = ~at_bound & ~no_effect
    idx = np.flatnonzero(free)
    cov = np.full((p, p), np.nan)
    flat_partners: dict[int, set[int]] = {i: set() for i in range(p)}
    if idx.size:
        ds = d[idx]
        an = a[np.ix_(idx, idx)] / np.outer(ds, ds)
        bn = b[np.ix_(idx, idx)] / np.outer(ds, ds)
        lam, vec = np.linalg.eigh(an)
        keep = lam > FLAT * lam.max()
        inv = (vec[:, keep] / lam[keep]) @ vec[:, keep].T
        dof = max(n - idx.size, 1)
        c = (n / dof) * inv @ bn @ inv / np.outer(ds, ds) * k  # every k-th bin: 1/k the data
        cov[np.ix_(idx, idx)] = c
        for j in np.flatnonzero(~keep):  # the flat directions and who lies along them
            members = idx[np.abs(vec[:, j]) > 0.1]
            for m in members:
                flat_partners[int(m)] |= {int(x) for x in members if x != m}
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se, se)
    with np.errstate(invalid="ignore", divide="ignore"):
        se_u = se / np.abs(slopes)
    scale = _scale(model, theta)

    # a diffuse held at 0 in every channel leaves the lobe all the reflectance there is:
    # its scale's standard error then measures a trade-off (ks with f0, where the
    # samples stop short of the Fresnel rise), not whether it is there (a gold paint's
    # Cornell samples, kd 0, read "alpha: no lobe" with alpha known to 0.002)
    kd = [j for j, name in enumerate(names) if name.split("[")[0] == "kd"]
    no_diffuse = bool(kd) and all(bound_side[j] < 0 for j in kd)

    def significant(scale_names, lobe: bool = True) -> bool:
        # a scale held at its upper bound (ks = 1 under the physical bounds) is a lobe
        # at its limit, not a vanished one: its partners are judged as any others; one
        # held at its lower bound (a coat's weight 4e-6, deep in its sigmoid's tail) is 0
        for j, name in enumerate(names):
            if name.split("[")[0] not in scale_names:
                continue
            if at_bound[j] and bound_side[j] > 0 and theta[j] > 0:
                return True
            if lobe and no_diffuse and bound_side[j] >= 0 and theta[j] > 0:
                return True
            if not at_bound[j] and np.isfinite(se[j]) and theta[j] > SIGNIFICANT * se[j]:
                return True
        return False

    layer_weight = {shape: weight for weight, shapes in model.layer_params.values()
                    for shape in shapes}
    reasons: list[str | None] = []
    for i in range(p):
        lobe = [x for x in LOBE_SCALE.get(names[i], ()) if x in names_of(model)]
        weight = layer_weight.get(names[i])
        # an absent lobe's or layer's shape is undetermined at a bound too: there the
        # bound, not the data, holds it (a noisy diffuse table's phong read n = 0.1 "at
        # bound" and determined beside a ks of 0.006 +- 0.005)
        if lobe and not significant(lobe):
            reasons.append(f"no lobe: {' and '.join(lobe)} within {SIGNIFICANT:g} standard "
                           "errors of 0 in every channel")
        elif weight is not None and not significant((weight,), lobe=False):
            reasons.append(f"no layer: {weight} within {SIGNIFICANT:g} standard errors of 0"
                           f"{' in every channel' if _is_rgb(model, weight) else ''}")
        elif at_bound[i]:
            reasons.append(None)
        elif no_effect[i]:
            reasons.append("no effect: the residuals do not depend on it")
        elif flat_partners[i]:
            reasons.append("trades off with " + ", ".join(names[j] for j in
                                                          sorted(flat_partners[i])))
        elif not np.isfinite(se[i]) or se[i] > LOOSE * scale[i]:
            reasons.append(f"loose: standard error {se[i]:.3g} against a scale of "
                           f"{scale[i]:.3g}")
        else:
            reasons.append(None)
    undetermined = [r is not None for r in reasons]
    # A flat direction has no finite error along it; say so rather than print a number.
    # Nor has the shape of a lobe or layer that is not there: alpha of a diffuse table
    # read "1.117 +- 0.011" in the JSON beside its flag, a figure its value does not have.
    vanished = [error_measures_nothing(r) for r in reasons]
    se_out = [None if (at_bound[i] or no_effect[i] or flat_partners[i] or vanished[i])
              else float(se[i]) for i in range(p)]
    se_u_out = [None if x is None else float(se_u[i]) for i, x in enumerate(se_out)]
    corr_out = [[None if not np.isfinite(corr[i, j]) else float(np.clip(corr[i, j], -1, 1))
                 for j in range(p)] for i in range(p)]
    strong = [[names[j] for j in range(p) if j != i and corr_out[i][j] is not None
               and abs(corr_out[i][j]) > STRONG_CORRELATION] for i in range(p)]
    strongly_correlated = {names[i]: strong[i] for i in range(p) if strong[i]}
    return {
        "method": "sandwich",
        "entries": names,
        "std_error": _grouped(model, se_out),
        "std_error_transformed": _grouped(model, se_u_out),
        "correlation": corr_out,
        "undetermined": _grouped(model, undetermined),
        "at_bound": _grouped(model, [bool(x) for x in at_bound]),
        "why": {names[i]: reasons[i] for i in range(p) if reasons[i] is not None},
        "strongly_correlated": strongly_correlated,
        "layers": _layers(model, names, reasons, significant, strongly_correlated,
                          bounded=[names[i] for i in range(p) if at_bound[i]]),
        "residuals": n,
        "jacobian_every": k,
    }


def _is_rgb(model: AbstractBRDFModel, name: str) -> bool:
    return any(s.rgb for s in model.param_specs if s.name == name)


def _layers(model: AbstractBRDFModel, names: list[str], reasons: list[str | None],
            significant, strongly_correlated: dict | None = None,
            bounded: list[str] = ()) -> dict:
    """Each of the model's layers (``model.layer_params``) as the data determine it:
    ``identified`` (its weight is above 0 by more than its error and every parameter
    of it is determined), ``absent`` (its weight is within its error of 0: the data show
    no such layer, and what shapes it means nothing), or ``unresolved`` (the layer is
    there, but some of its parameters are not pinned down: which, and why). An
    identified layer whose own parameters correlate beyond 0.95 says so: each is
    determined, but the data tell them apart only together; one whose shape sits at a
    bound (``bounded``) says that too: the data would take it further
    (color-changing-paint3's film ended at the thinnest, least refractive film
    allowed, and read "each determined by the data")."""
    out = {}
    for layer, (weight, shapes) in model.layer_params.items():
        if not significant((weight,)):
            out[layer] = {"status": "absent",
                          "why": f"{weight} within {SIGNIFICANT:g} standard errors of 0: the "
                                 f"data show no {layer}"}
            continue
        own = (weight, *shapes)
        loose = [(names[i], reasons[i]) for i in range(len(names))
                 if names[i].split("[")[0] in own and reasons[i] is not None]
        if loose:
            out[layer] = {"status": "unresolved",
                          "why": "; ".join(f"{name}: {why}" for name, why in loose)}
            continue
        entries = [n for n in names if n.split("[")[0] in own]
        tied = sorted({n for n in entries for other in (strongly_correlated or {}).get(n, ())
                       if other.split("[")[0] in own and other.split("[")[0] != n.split("[")[0]})
        held = [n for n in entries if n in bounded and n.split("[")[0] != weight]
        out[layer] = {"status": "identified",
                      "why": f"{', '.join(own)} each determined by the data" + (
                          f"; {', '.join(tied)} correlate beyond {STRONG_CORRELATION:g}: the "
                          "data tell them apart only together" if tied else "") + (
                          f"; {', '.join(held)} at the model's bound: the data would take "
                          f"{'it' if len(held) == 1 else 'them'} further" if held else "")}
    return out
