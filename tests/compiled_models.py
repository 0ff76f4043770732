"""A model's values (:func:`evaluate`) and its hemisphere-wide finiteness checks,
each as one compiled program.

Op by op (``jax.grad`` outside ``jit``) every primitive of a model and of its
derivative compiles on its own, once per test process: the same checks took ~3x as
long that way (issue 25). Compiled, they also check what a fit runs, which is a
compiled model, not an op-by-op one.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdffit import executables


def evaluate(m, p, wi, wo):
    """``m(p, wi, wo)`` as one compiled program, compiled once per model and array
    shapes: op by op, every primitive of the model compiles on its own. The values
    and directions go in as arrays (the model's own arrays too, as a fit passes
    them), so that other values reuse the program; a Python number left as it is
    would be a constant of the program, compiled again for each value."""
    p = {k: jnp.asarray(v) for k, v in p.items()}
    return _evaluate(m, p, jnp.asarray(wi), jnp.asarray(wo))


#: XLA options for a check's own programs (a model's gradients, its values): brdffit's
#: own (no fusion emitters), so that a check runs what a fit compiles, and compiles as
#: fast: with XLA's defaults, standard_surface_coat's values and gradients took 5.9 s
#: to compile, 4.7 s so.
CHECK_COMPILER_OPTIONS = dict(executables.CPU_COMPILER_OPTIONS)
#: ... and for two formulations of one quantity compared to rounding (a Jacobian by
#: columns against jacfwd's), no optimisation as well: 3.0 s for the program above.
#: Not for a finiteness check, whose subject is the program a fit runs: unoptimised,
#: the film's forward-mode slopes came out non-finite at one edge (a fit's program
#: has them finite), and a Phong lobe differed from its shared program's by 8e-11.
COMPARISON_COMPILER_OPTIONS = {**CHECK_COMPILER_OPTIONS,
                               "xla_backend_optimization_level": 0,
                               "xla_llvm_disable_expensive_passes": True}


def check_jit(fn, *, comparison: bool = False):
    """``fn`` compiled as ``eqx.filter_jit`` does (arrays traced, everything else
    static), with :data:`CHECK_COMPILER_OPTIONS` (``comparison``:
    :data:`COMPARISON_COMPILER_OPTIONS`); once per argument structure and shapes."""
    options = COMPARISON_COMPILER_OPTIONS if comparison else CHECK_COMPILER_OPTIONS
    programs: dict = {}

    def call(*args):
        dynamic, static = eqx.partition(args, eqx.is_array)
        leaves, treedef = jax.tree_util.tree_flatten(dynamic)
        statics, static_def = jax.tree_util.tree_flatten(static)
        key = (treedef, static_def, tuple((x.shape, x.dtype) for x in leaves),
               tuple(x if isinstance(x, (str, int, float, bool, type(None))) else id(x)
                     for x in statics))
        if key not in programs:
            lowered = jax.jit(lambda d: fn(*eqx.combine(d, static))).lower(dynamic)
            programs[key] = (lowered.compile(compiler_options=options)
                             if jax.default_backend() == "cpu" else lowered.compile(),
                             static)  # kept alive: its id is in the key
        return programs[key][0](dynamic)

    return call


#: a model's values, one program per model and shapes (the model is static: its id)
_evaluate = check_jit(lambda m, p, wi, wo: m(p, wi, wo))


def _all_finite(tree) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(x)))) for x in jax.tree_util.tree_leaves(tree))


def assert_finite_values_and_gradients(m, param_sets, wi, wo) -> None:
    """For every parameter set: values finite and >= 0, and finite gradients with
    respect to the parameters and to both directions, in reverse mode and in forward
    mode (the lm solver's Jacobian of a lobe's shape is forward mode: a quotient
    rule whose floored denominator squared to 0 gave NaN slopes at exactly normal
    incidence there, which reverse mode never showed)."""

    @check_jit
    def values_and_gradients(p, wi, wo):
        return (m(p, wi, wo),
                jax.grad(lambda q: jnp.sum(m(q, wi, wo)))(p),
                jax.grad(lambda a, b: jnp.sum(m(p, a, b)), argnums=(0, 1))(wi, wo),
                jax.jacfwd(lambda q: m(q, wi, wo))(p))

    for params in param_sets:
        p = {s.name: jnp.asarray(params[s.name], jnp.float64) * (jnp.ones(3) if s.rgb else 1.0)
             for s in m.param_specs}
        f, g_params, g_dirs, forward = values_and_gradients(p, wi, wo)
        assert _all_finite(f) and bool(jnp.all(f >= 0)), params
        for k, g in g_params.items():
            assert _all_finite(g), (params, k)
            assert _all_finite(forward[k]), (params, k, "forward mode")
        assert _all_finite(g_dirs), params


def assert_finite_transform_gradients(m, u, wi, wo, scales=(-50.0, 0.0, 50.0)) -> None:
    """Finite gradients through the parameter transforms with every unconstrained
    value at each of ``scales`` (the defaults lie beyond both ends of every transform)."""
    gradient = check_jit(jax.grad(lambda v: jnp.sum(m(m.constrain(v), wi, wo))))
    for scale in scales:
        assert _all_finite(gradient(jnp.full_like(u, scale))), scale
