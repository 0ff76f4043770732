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


@eqx.filter_jit
def _evaluate(m, p, wi, wo):
    return m(p, wi, wo)


def evaluate(m, p, wi, wo):
    """``m(p, wi, wo)`` as one compiled program, compiled once per model and array
    shapes: op by op, every primitive of the model compiles on its own. The values
    and directions go in as arrays (the model's own arrays too, as a fit passes
    them), so that other values reuse the program; a Python number left as it is
    would be a constant of the program, compiled again for each value."""
    p = {k: jnp.asarray(v) for k, v in p.items()}
    return _evaluate(m, p, jnp.asarray(wi), jnp.asarray(wo))


def _all_finite(tree) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(x)))) for x in jax.tree_util.tree_leaves(tree))


def assert_finite_values_and_gradients(m, param_sets, wi, wo) -> None:
    """For every parameter set: values finite and >= 0, and finite gradients with
    respect to the parameters and to both directions, in reverse mode and in forward
    mode (the lm solver's Jacobian of a lobe's shape is forward mode: a quotient
    rule whose floored denominator squared to 0 gave NaN slopes at exactly normal
    incidence there, which reverse mode never showed)."""

    @jax.jit
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
    gradient = jax.jit(jax.grad(lambda v: jnp.sum(m(m.constrain(v), wi, wo))))
    for scale in scales:
        assert _all_finite(gradient(jnp.full_like(u, scale))), scale
