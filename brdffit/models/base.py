"""What every BRDF model is: named, bounded parameters and a vectorised evaluation.

A model is an immutable :class:`equinox.Module` (its configuration, if any, as
static fields). ``model(params, wi, wo)`` evaluates one batch of direction pairs;
batching over parameters or tables is the caller's ``jax.vmap``.

Parameters are a ``dict`` keyed by the docs/models.md names; RGB parameters have shape
``(3,)``, shape parameters are scalars. Fitting works on an unconstrained vector
``u`` and maps it to the bounded parameters with :meth:`ParamSpec.constrain`.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .frame import Frame, shading_frame

Params = dict[str, Array]


#: |u| beyond which softplus and sigmoid have slope < 1e-5: a parameter there is at
#: its bound for every purpose of a fit (kd = 1e-5 is black; f0 = 1 - 1e-5 is 1).
_TAIL_U = 11.5
#: :meth:`AbstractBRDFModel.solver_bound_side`'s mark of a layer's shape coordinate
#: while the layer's weight sits in its lower tail, beside -1 / +1 (a lower / upper
#: tail): ``HELD + i``, ``i`` the weight's coordinate. The solver holds it still where
#: it pins that weight (``brdffit.fitting.solver.pinned_coordinates``).
HELD = 2


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: its docs/models.md name, range, and how a fit keeps it in range.

    ``scale="log"`` spaces a bounded interval logarithmically (``alpha``, ``n``):
    a step of the optimiser then changes the parameter by a ratio, which is what
    lobe widths need. An interval with no upper bound uses a softplus.
    """

    name: str
    doc: str
    lower: float = 0.0
    upper: float | None = None
    rgb: bool = False
    scale: str = "linear"

    @property
    def size(self) -> int:
        return 3 if self.rgb else 1

    def describe_range(self) -> str:
        hi = "inf" if self.upper is None else f"{self.upper:g}"
        return f"[{self.lower:g}, {hi}]" + (" (log)" if self.scale == "log" else "")

    def constrain(self, u: Array) -> Array:
        """Unconstrained -> parameter value, smooth and strictly inside the range."""
        if self.upper is None:
            return self.lower + jax.nn.softplus(u)
        s = jax.nn.sigmoid(u)
        if self.scale == "log":
            lo, hi = math.log(self.lower), math.log(self.upper)
            # exp(log(hi)) can round above hi: a fitted value must pass check_params
            return jnp.clip(jnp.exp(lo + (hi - lo) * s), self.lower, self.upper)
        return self.lower + (self.upper - self.lower) * s

    def bound_side(self, u: Array) -> Array:
        """-1 or +1 where ``u`` sits in a flat tail of the transform (the parameter
        is at its lower or upper bound to ~1e-5 of its scale), else 0.

        A fit cannot reach a bound, only approach it along a tail where the
        transform's slope vanishes; the solver treats such a coordinate as at the
        bound (``brdffit.fitting.solver``) instead of chasing it there step by step.
        """
        if self.upper is None:  # softplus: only u -> -inf is a bound
            return jnp.where(u < -_TAIL_U, -1, 0).astype(jnp.int32)
        return jnp.where(jnp.abs(u) > _TAIL_U, jnp.sign(u), 0).astype(jnp.int32)

    def unconstrain(self, value) -> np.ndarray:
        """Inverse of :meth:`constrain` (numpy, for initial values); clips into range."""
        v = np.asarray(value, dtype=np.float64)
        if self.upper is None:
            x = np.maximum(v - self.lower, 1e-12)
            # inverse softplus, stable for large x
            return x + np.log(-np.expm1(-x))
        if self.scale == "log":
            lo, hi = math.log(self.lower), math.log(self.upper)
            s = (np.log(np.clip(v, self.lower, self.upper)) - lo) / (hi - lo)
        else:
            s = (v - self.lower) / (self.upper - self.lower)
        s = np.clip(s, 1e-6, 1 - 1e-6)  # |u| <= 14: a start at a bound can still move
        return np.log(s) - np.log1p(-s)


def _at_most_one(spec: ParamSpec) -> ParamSpec:
    """``spec`` with its upper bound lowered to 1 (a reflectance's physical range)."""
    if spec.upper is not None and spec.upper <= 1.0:
        return spec
    return dataclasses.replace(spec, upper=1.0)


KD = ParamSpec("kd", "diffuse albedo (RGB)", 0.0, None, rgb=True)
KS = ParamSpec("ks", "specular scale (RGB)", 0.0, None, rgb=True)


class AbstractBRDFModel(eqx.Module):
    """A BRDF f_r(wi, wo) in 1/sr, RGB, never multiplied by the cosine."""

    name: ClassVar[str]
    param_specs: ClassVar[tuple[ParamSpec, ...]]
    #: Shape-parameter values tried when seeding a fit (see brdffit.fitting.starts).
    shape_grid: ClassVar[tuple[dict[str, float], ...]] = ({},)
    #: A shape parameter of ``shape_grid`` whose values are separate basins of the loss
    #: (standard_surface's ``metalness``: a metal and a dielectric explain a highlight
    #: differently), or None. A fit then refines the best-scored start of each of its
    #: values too, not only the best starts overall (brdffit.fitting.pipeline).
    start_family: ClassVar[str | None] = None
    #: The registry name of a model this one contains as a special case (ggx2
    #: contains ggx), or None. A fit seeds itself from the parent's optimum
    #: (:meth:`embed_parent`), so it can never end worse than its parent.
    parent: ClassVar[str | None] = None
    #: Values of what this model adds to its parent (a layer's parameters), each tried
    #: over the parent's optimum as one more start candidate, scored with the rest
    #: (brdffit.fitting.pipeline): for a layer whose loss is many-moded in its own
    #: parameters (a thin film's thickness), where the parent's optimum with the layer
    #: off is a point from which no gradient finds them. Empty: none.
    parent_scan: ClassVar[tuple[dict, ...]] = ()
    #: Values of what this model adds, just off its parent's embedding (oren_nayar's
    #: sigma a little above 0), each tried over the parent's optimum before this
    #: model's own starts are solved: where none lowers the loss, the parent's optimum
    #: is a stationary point of this model's loss with the addition at its bound, and
    #: the fit ends there ("nested: no gain", brdffit.fitting.pipeline) without solving
    #: its own starts. For an addition whose loss is one basin in it, so that no
    #: descent at the bound means none further out (checked on the 100 MERL
    #: materials for oren_nayar, docs/fitting.md). Empty: its own starts are solved.
    first_order_probes: ClassVar[tuple[dict, ...]] = ()
    #: The fewest starts a fit of this model refines (more where asked), for a model
    #: whose best-scored start candidate often lies in another mode than the optimum
    #: (a thin film's); the result's notes say so where it is more than was asked.
    least_starts: ClassVar[int] = 1
    #: The layers this model has over a single base material, by their kind
    #: (``"clearcoat"``, ``"sheen"``, ``"iridescence"``), each as (its weight, the
    #: parameters that shape it): an export into a model without one of them says what
    #: was lost (``brdffit.export``), and a layer whose weight the data cannot tell from
    #: 0 is absent, its shape meaning nothing (``brdffit.fitting.uncertainty``).
    layer_params: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = {}
    #: Whether the solver holds a layer's shape parameters still while its weight sits
    #: at 0 (in its transform's lower tail) and is pinned there (the data push it
    #: outward; :meth:`solver_bound_side`): they then change nothing the data can see,
    #: and a linear model of them promises steps that the loss never delivers. An
    #: absent thin film over gold-paint crawled 256 steps from its base's own optimum
    #: without ever passing the optimality test (its thickness's and index's columns
    #: ~1e-12 of the largest, their promised decrement 13% of the loss). Held on the
    #: tail alone, a start embedded from the base could never turn its layer on
    #: (nickel's film was lost: 5.7% of log_rmse). Opt-in per model; the weight must be
    #: a scalar, and is pinned as before.
    holds_absent_layers: ClassVar[bool] = False
    #: Whether ``model="auto"`` tries this model by default (``brdffit.selection``): the
    #: docs/models.md models are candidates; a renderer's target model is not (its fit
    #: is what an export makes, not a choice among the measured material's models).
    auto_candidate: ClassVar[bool] = False
    #: A well-posed set of parameters (docs/models.md names) that a fit of a table made
    #: from them recovers: the tests' ground truth for every model that gives one, so a
    #: new model is tested by giving it (tests/truths.py). None: not tested that way.
    example_params: ClassVar[dict | None] = None
    #: For a model of the form ``f = kd/pi + sum_k scale_k * lobe_k`` (each scale an
    #: RGB parameter, each lobe shared by R, G and B): the scales' names, in the order
    #: of :meth:`unit_lobes`. The fit then forms its normal equations in closed form
    #: in the colour parameters and differentiates only the lobes' few shape
    #: parameters (``brdffit.fitting.loss.normal_equations``). Empty: any other model.
    lobe_scales: ClassVar[tuple[str, ...]] = ()

    @property
    def physical_specs(self) -> tuple[ParamSpec, ...]:
        """:attr:`param_specs` with each reflectance at most 1: the ranges of a
        physically bounded fit (``fit(..., physical=True)``, brdffit.fitting.physical).

        The reflectances are ``kd`` (a diffuse albedo) and the lobe scales
        (:attr:`lobe_scales`; ``ks`` of every one-lobe model): ``ks F(cos_d)`` is the
        facets' reflectance and F reaches 1 at grazing, so ``ks <= 1``. A range that
        is already within [0, 1] (``f0``, glTF's factors) is kept.
        """
        return tuple(_at_most_one(s) if s.name in ("kd", *self.lobe_scales) else s
                     for s in self.param_specs)

    def unit_lobes(self, shape: Params, frame: Frame) -> Float[Array, "k ..."]:
        """The lobes for unit scales, stacked (k, ...); ``shape`` holds the non-RGB
        parameters only. Needed where :attr:`lobe_scales` is not empty."""
        raise NotImplementedError(f"{self.name} declares no lobes")

    def compiled_form(self) -> AbstractBRDFModel:
        """The model that compiled programs take in this one's place
        (``brdffit.executables``): itself, but for a member of a family of lobe
        models that share their programs (:func:`share_programs`)."""
        return self

    @property
    def layers(self) -> tuple[str, ...]:
        """The kinds of :attr:`layer_params`, in its order (none: a single material)."""
        return tuple(self.layer_params)

    def embed_parent(self, parent_params: dict) -> dict:
        """The parent's parameters as a point of this model with the same values."""
        raise NotImplementedError(f"{self.name} contains no other model")

    @abc.abstractmethod
    def eval_frame(self, params: Params, frame: Frame) -> Float[Array, "... 3"]:
        """The BRDF on precomputed frame quantities."""

    def eval_channels(self, params: Params, frame: Frame) -> Float[Array, "3 ..."]:
        """The BRDF channel-major, (3, ...): the layout the fitting loss uses
        (vectorises along the bins). Models with structure override it."""
        return jnp.moveaxis(self.eval_frame(params, frame), -1, 0)

    def __call__(
        self, params: Params, wi: Float[Array, "... 3"], wo: Float[Array, "... 3"]
    ) -> Float[Array, "... 3"]:
        return self.eval_frame(params, shading_frame(wi, wo))

    # -- parameter vectors -------------------------------------------------------

    @property
    def n_params(self) -> int:
        return sum(s.size for s in self.param_specs)

    def constrain(self, u: Float[Array, " n"]) -> Params:
        """Unconstrained vector -> parameter dict."""
        out, i = {}, 0
        for spec in self.param_specs:
            chunk = u[i : i + spec.size]
            out[spec.name] = spec.constrain(chunk if spec.rgb else chunk[0])
            i += spec.size
        return out

    def unconstrain(self, params: dict) -> np.ndarray:
        """Parameter dict (floats, lists or arrays) -> unconstrained numpy vector."""
        parts = []
        for spec in self.param_specs:
            v = np.broadcast_to(np.asarray(params[spec.name], np.float64), (spec.size,))
            parts.append(spec.unconstrain(v))
        return np.concatenate(parts)

    def unconstrain_rows(self, params: dict) -> np.ndarray:
        """:meth:`unconstrain` of K parameter sets at once, each value (K,) or (K, size)
        -> (K, n): the same numbers, without a Python call per start (a grid of 70
        starts took ~15 ms one by one)."""
        parts = []
        for spec in self.param_specs:
            v = np.asarray(params[spec.name], np.float64)
            k = v.shape[0]
            parts.append(spec.unconstrain(np.broadcast_to(v.reshape(k, -1), (k, spec.size))))
        return np.concatenate(parts, axis=1)

    def unbounded_above(self) -> np.ndarray:
        """Per coordinate: True on a softplus (a scale with no upper bound, so no
        upper tail either: the solver's step there is relative, and a polish does not
        clip it), False on a sigmoid."""
        return np.concatenate([np.full(s.size, s.upper is None) for s in self.param_specs])

    def bound_side(self, u: Float[Array, " n"]) -> Array:
        """Per coordinate of ``u``: -1 / +1 at the lower / upper bound, else 0
        (:meth:`ParamSpec.bound_side`)."""
        parts, i = [], 0
        for spec in self.param_specs:
            parts.append(jnp.broadcast_to(spec.bound_side(u[i : i + spec.size]), (spec.size,)))
            i += spec.size
        return jnp.concatenate(parts).astype(jnp.int32)

    def solver_bound_side(self, u: Float[Array, " n"]) -> Array:
        """:meth:`bound_side` as the solver reads it: where
        :attr:`holds_absent_layers`, a layer's shape coordinates are ``HELD + i`` while
        its weight (coordinate ``i``, a scalar) sits in its lower tail."""
        side = self.bound_side(u)
        if not self.holds_absent_layers or not self.layer_params:
            return side
        where, i = {}, 0
        for spec in self.param_specs:
            where[spec.name] = slice(i, i + spec.size)
            i += spec.size
        for weight, shapes in self.layer_params.values():
            i = where[weight].start
            off = side[i] == -1
            for shape in shapes:
                side = side.at[where[shape]].set(jnp.where(off, HELD + i, side[where[shape]]))
        return side

    def check_params(self, params: dict) -> dict:
        """Validate a user-given parameter dict; returns it with numpy values.

        Raises ``ValueError`` naming the parameter for a missing, unknown, badly
        shaped, non-finite or out-of-range value.
        """
        names = {s.name for s in self.param_specs}
        unknown = set(params) - names
        if unknown:
            raise ValueError(
                f"{self.name}: unknown parameter(s) {sorted(unknown)}; expected {sorted(names)}"
            )
        out = {}
        for spec in self.param_specs:
            if spec.name not in params:
                raise ValueError(f"{self.name}: missing parameter {spec.name!r}")
            try:
                # numbers only: numpy reads "0.15" as 0.15 and True as 1.0, and an
                # export of a hand-edited result took alpha: true as a roughness of 1
                if np.asarray(params[spec.name]).dtype.kind not in "iuf":
                    raise TypeError
                v = np.asarray(params[spec.name], dtype=np.float64)
            except (TypeError, ValueError):
                raise ValueError(f"{self.name}: {spec.name} must be a number"
                                 + (" or three" if spec.rgb else "")
                                 + f", got {params[spec.name]!r}") from None
            if v.size == 1 and spec.rgb:
                v = np.full(3, float(v.reshape(())))
            if v.shape not in ((spec.size,), ()) or v.size != spec.size:
                # by shape: [[0.1], [0.1], [0.1]] is 3 values, nested, and "needs 3,
                # got 3" said nothing
                got = (f"{v.size}" if v.ndim <= 1
                       else f"an array of shape {list(v.shape)}, not a flat list")
                raise ValueError(
                    f"{self.name}: {spec.name} needs {spec.size} value(s), got {got}"
                )
            if not np.all(np.isfinite(v)):
                raise ValueError(f"{self.name}: {spec.name} is not finite")
            hi = np.inf if spec.upper is None else spec.upper
            if np.any(v < spec.lower) or np.any(v > hi):
                raise ValueError(
                    f"{self.name}: {spec.name}={v.tolist()} outside {spec.describe_range()}"
                )
            out[spec.name] = v if spec.rgb else v.reshape(())
        return out


class AbstractLobeModel(AbstractBRDFModel):
    """``f = kd/pi + ks * lobe``: a Lambertian base plus one specular lobe.

    Subclasses define :meth:`lobe` (a scalar field over the batch) and the
    lobe's shape parameters after ``kd`` and ``ks``.
    """

    lobe_scales = ("ks",)
    #: Whether this model's programs are its family's (:func:`share_programs`): set
    #: where several members are fitted together (:func:`sharing_where_it_pays`); a
    #: fit of one model alone compiles its own, smaller programs.
    shared_programs: bool = eqx.field(static=True, default=False)

    def unit_lobes(self, shape: Params, frame: Frame) -> Float[Array, "1 ..."]:
        return self.lobe(shape, frame)[None]

    @abc.abstractmethod
    def lobe(self, params: Params, frame: Frame) -> Float[Array, ...]:
        """The lobe's value (1/sr) for unit ``ks``; shared by the three channels."""

    def eval_frame(self, params: Params, frame: Frame) -> Float[Array, "... 3"]:
        lobe = self.lobe(params, frame)[..., None]
        return params["kd"] / jnp.pi + params["ks"] * lobe

    def eval_channels(self, params: Params, frame: Frame) -> Float[Array, "3 ..."]:
        lobe = self.lobe(params, frame)
        kd, ks = params["kd"], params["ks"]
        expand = (slice(None),) + (None,) * lobe.ndim
        return kd[expand] / jnp.pi + ks[expand] * lobe[None]

    def compiled_form(self) -> AbstractBRDFModel:
        family = _PROGRAM_FAMILIES.get(type(self))
        if family is None or not self.shared_programs:
            return self
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        fields["shared_programs"] = False
        return SharedLobe(members=tuple(cls(**fields) for cls in family),
                          which=np.asarray(family.index(type(self)), np.int32))


# -- lobe models that share their compiled programs ----------------------------------

#: A lobe-model class -> its family (:func:`share_programs`).
_PROGRAM_FAMILIES: dict[type, tuple[type, ...]] = {}


def share_programs(*family: type[AbstractLobeModel]) -> None:
    """Let these lobe-model classes share their compiled programs.

    Blinn-Phong and Phong have the same parameters (``kd``, ``ks``, ``n``), and so do
    Beckmann and GGX (``kd``, ``ks``, ``alpha`` and ``f0``, or ``eta`` for the
    dielectric Fresnel): a fit of one differs from a fit of the other in the lobe
    alone. Every compiled program of a fit (the solve, the starts' scores, the
    full-table error, the sphere renders, the linearisation) takes a model's
    :meth:`~AbstractBRDFModel.compiled_form` in its place (``brdffit.executables``):
    for a member of a family, one :class:`SharedLobe` of the whole family, so that
    one compiled program serves every member and ``auto``, which fits all four,
    compiles two of each program instead of four (docs/fitting.md has the figures).
    Only where a model says so (``shared_programs``; :func:`sharing_where_it_pays`
    sets it where two or more members are fitted together): a family's program holds
    every member's lobe, so a process that fits one model alone compiles its own,
    smaller one.

    The classes must be lobe models with the same parameters and fields (a member is
    built from another's field values). Membership is by class: a subclass (another
    lobe under a built-in's name) keeps programs of its own. The registry declares
    the built-in families (``brdffit.models.registry``).
    """
    specs = {cls().param_specs for cls in family}
    if len(family) < 2 or len(specs) != 1 or not all(
            issubclass(cls, AbstractLobeModel) for cls in family):
        raise ValueError(f"a family is two or more lobe models of the same parameters, "
                         f"not {[cls.__name__ for cls in family]}")
    for cls in family:
        _PROGRAM_FAMILIES[cls] = tuple(family)


def with_shared_programs(model: AbstractBRDFModel) -> AbstractBRDFModel:
    """``model`` taking its family's compiled programs (:func:`share_programs`); a
    model of no family as it is."""
    if type(model) not in _PROGRAM_FAMILIES:
        return model
    return dataclasses.replace(model, shared_programs=True)


def sharing_where_it_pays(models: list[AbstractBRDFModel]) -> list[AbstractBRDFModel]:
    """``models``, to be fitted in one process, each with its family's programs
    (:func:`with_shared_programs`) where two or more of them share one family program
    (``auto``'s candidates, a request's or a batch's list); a lone member keeps its
    own, smaller programs."""
    shared = [with_shared_programs(m) for m in models]
    forms = [m.compiled_form() for m in shared]
    keys = [f.members if isinstance(f, SharedLobe) else None for f in forms]
    return [s if key is not None and keys.count(key) >= 2 else m
            for m, s, key in zip(models, shared, keys, strict=True)]


class SharedLobe(AbstractLobeModel):
    """The members of one family (:func:`share_programs`) as one model: ``kd/pi + ks *
    lobe`` with the lobe of ``members[which]``, ``which`` an int32 array (data, so one
    compiled program serves every member). Only the chosen branch runs (XLA's
    conditional): a member's values are its own, the same formulas rounded the same
    way (tests/test_shared_programs.py). Never fitted, named or reported itself: a
    fit's result names the member."""

    members: tuple[AbstractLobeModel, ...] = eqx.field(static=True, default=())
    which: Int[Array, ""] | None = None

    @property
    def name(self) -> str:
        return "|".join(m.name for m in self.members)

    @property
    def param_specs(self) -> tuple[ParamSpec, ...]:
        return self.members[0].param_specs

    def lobe(self, params: Params, frame: Frame) -> Float[Array, ...]:
        return jax.lax.switch(self.which, [m.lobe for m in self.members], params, frame)
