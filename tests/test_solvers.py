"""brdffit.fitting.solver on small least-squares problems with known answers: the stop rule
(optimality, not small steps), bound-pinned coordinates, and honest failure codes."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from brdffit.fitting import solver as solvers
from brdffit.fitting.solver import NormalLevenbergMarquardt

pytestmark = pytest.mark.unit

# numpy, not jnp: module-level arrays are made at import, outside the tests' float64
T = np.linspace(0.0, 1.0, 64)


def _solve(fn, y0, options=None, max_steps=200):
    solver = NormalLevenbergMarquardt(rtol=1e-8, atol=1e-12)
    sol = optx.least_squares(fn, solver, y0, options=options, max_steps=max_steps, throw=False)
    return sol


# The checks at a solution, compiled: op by op, every primitive of the Jacobian and of
# the tests compiles on its own (seconds per test in a new process).
@functools.partial(jax.jit, static_argnums=0)
def _normal(fn, y):
    """sum r^2, J^T J and J^T r of ``fn`` at ``y``, as the solver forms them."""
    return solvers._residual_and_normal(lambda v, a: (fn(v, a), None), y, None, None)[:3]


is_optimal = jax.jit(solvers.is_optimal)
status = jax.jit(solvers.status)
decrement = jax.jit(solvers.decrement)


def _bounds(y, args):
    # coordinate 0 is a softplus-constrained scale: at its bound far down its tail
    return jnp.array([jnp.where(y[0] < -11.5, -1, 0), 0, 0], jnp.int32)


TARGET = 2.0 * np.exp(-3.0 * T) + 0.2 - 0.3 * T


def _pinned_problem(y, args):
    """A ramp of slope a = softplus(y0) >= 0 where the data has slope -0.3: the
    constrained optimum holds a at 0, and b, c must still be found."""
    return jax.nn.softplus(y[0]) * T + 2.0 * jnp.exp(-y[1] * T) + y[2] - TARGET


def test_a_coordinate_heading_for_its_bound_does_not_slow_the_others():
    from scipy.optimize import least_squares

    # the constrained optimum, independently: scipy with a as a bounded variable
    ref = least_squares(
        lambda p: np.asarray(p[0] * T + 2.0 * np.exp(-p[1] * T) + p[2] - TARGET),
        [0.5, 1.0, 0.0], bounds=([0.0, -np.inf, -np.inf], np.inf), xtol=1e-15, ftol=1e-15,
    )
    assert ref.x[0] == pytest.approx(0.0, abs=1e-8)
    y0 = jnp.array([-20.0, 1.0, 0.0])  # a already deep in its tail, as a dark ks channel
    sol = _solve(_pinned_problem, y0, options={"bound_side": _bounds})
    assert sol.result == optx.RESULTS.successful
    assert int(sol.stats["stop"]) == solvers.OPTIMAL
    # optimal to the test's promise: the loss within 1e-6 of the constrained optimum
    loss = float(jnp.sum(_pinned_problem(sol.value, None) ** 2))
    assert loss <= (1 + 1e-6) * 2 * ref.cost
    np.testing.assert_allclose(sol.value[1:], ref.x[1:], rtol=1e-2)
    assert int(sol.stats["num_steps"]) < 60


def test_without_bound_information_the_optimality_test_does_not_hold_there():
    """The decrement keeps promising what crossing the bound would give: the test
    alone (without pinning) must not call that point optimal."""
    sol = _solve(_pinned_problem, jnp.array([-20.0, 1.0, 0.0]),
                 options={"bound_side": _bounds})
    y = sol.value.at[0].set(-30.0)  # a = 1e-13: at its bound for every purpose
    loss, jtj, jtr = _normal(_pinned_problem, y)
    free = jnp.zeros(3, jnp.int32)
    assert not bool(is_optimal(loss, jtj, jtr, free, 1e-7, 0.0))
    assert bool(is_optimal(loss, jtj, jtr, _bounds(y, None), 1e-7, 0.0))
    # still in the tail but not yet at the bound: the pinned gain is counted
    y = y.at[0].set(-13.0)
    loss, jtj, jtr = _normal(_pinned_problem, y)
    assert not bool(is_optimal(loss, jtj, jtr, _bounds(y, None), 1e-7, 0.0))


def _gated_problem(y, args):
    """A layer of weight w = softplus(y0) and a shape y1 (a frequency, as a film's
    thickness: the loss many-moded in it) over a base y2 fitting the data alone: the
    optimum is w = 0, where y1 changes nothing the data show."""
    return y[2] - jax.nn.softplus(y[0]) * jnp.sin(7.0 * y[1] * T) - TARGET


def _gated_bounds(held: bool):
    def sides(y, args):
        off = y[0] < -11.5
        shape = jnp.where(off, solvers.HELD + 0, 0) if held else 0  # held by coordinate 0
        return jnp.array([jnp.where(off, -1, 0), shape, 0], jnp.int32)
    return sides


def test_a_layer_that_is_off_holds_its_shape_and_the_fit_ends_optimal():
    """At w ~ 1e-9 the shape's column is ~1e-9 of the base's: free, it kept a linear
    model promising a decrease the loss never gave (a thin film's thickness over its
    absent film: 256 steps, never optimal). HELD, it stays where it is, promises
    nothing, and the weight heads for its bound as any pinned coordinate. Where the
    data pull the weight back in, the shape is free again."""
    y0 = jnp.array([-20.0, 1.3, 0.0])
    y = jnp.array([-20.7, 1.3, TARGET.mean()])  # the base at its optimum, the layer off
    loss, jtj, jtr = _normal(_gated_problem, y)
    side_free, side_held = _gated_bounds(False)(y, None), _gated_bounds(True)(y, None)
    assert not bool(is_optimal(loss, jtj, jtr, side_free, 1e-7, 0.0))
    assert bool(is_optimal(loss, jtj, jtr, side_held, 1e-7, 0.0))
    pinned = solvers.pinned_coordinates(jtj, jtr, side_held)
    assert bool(pinned[1]) and not bool(pinned[2])
    sol = _solve(_gated_problem, y0, options={"bound_side": _gated_bounds(True)})
    assert int(sol.stats["stop"]) == solvers.OPTIMAL
    assert float(sol.value[1]) == 1.3  # held: not moved
    np.testing.assert_allclose(float(sol.value[2]), TARGET.mean(), rtol=1e-6)
    # the layer pulled in (the sign flipped: a positive weight now helps): not pinned,
    # so its shape is free
    flipped = lambda y, a: y[2] + jax.nn.softplus(y[0]) * jnp.sin(7.0 * y[1] * T) - TARGET  # noqa: E731
    loss, jtj, jtr = _normal(flipped, y)
    pinned = solvers.pinned_coordinates(jtj, jtr, side_held)
    assert not bool(pinned[0]) and not bool(pinned[1])


def test_exact_fit_converges_through_the_floor_not_the_decrement():
    def fn(y, args):
        return y[0] * jnp.exp(-y[1] * T) - 1.5 * jnp.exp(-2.0 * T)

    sol = _solve(fn, jnp.array([1.0, 1.0]), options={"loss_floor": 1e-24})
    assert sol.result == optx.RESULTS.successful
    np.testing.assert_allclose(sol.value, [1.5, 2.0], rtol=1e-9)


def test_step_limit_is_not_success():
    def fn(y, args):
        return y[0] * jnp.exp(-y[1] * T) - 1.5 * jnp.exp(-2.0 * T) + 0.01 * jnp.sin(9 * T)

    sol = _solve(fn, jnp.array([0.1, 8.0]), max_steps=2)
    assert sol.result == optx.RESULTS.nonlinear_max_steps_reached
    loss, jtj, jtr = _normal(fn, sol.value)
    s = status(sol.result, is_optimal(loss, jtj, jtr, jnp.zeros(2, jnp.int32), 1e-7, 0.0))
    assert solvers.STATUS_NAMES[int(s)] == "nonlinear_max_steps_reached"


def test_a_kink_stalls_and_says_so():
    """|y| has no derivative at its minimum: the linear model keeps promising, no
    step delivers, the damping runs away. That is a stall, never a success."""

    def fn(y, args):
        return jnp.abs(y) + 1.0

    sol = _solve(fn, jnp.array([0.3]), max_steps=500)
    assert int(sol.stats["stop"]) in (solvers.STUCK, solvers.STALLED)
    loss, jtj, jtr = _normal(fn, sol.value)
    optimal = is_optimal(loss, jtj, jtr, jnp.zeros(1, jnp.int32), 1e-7, 0.0)
    assert solvers.STATUS_NAMES[int(status(sol.result, optimal))] == "stalled"


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_gtol_and_floor_are_relative(dtype):
    """Scaling every residual by 1e-6 changes neither the decrement test nor the
    exact-fit floor's verdict (both are relative to the problem's own scale)."""
    jtj = jnp.array([[2.0, 0.3], [0.3, 1.0]], dtype)
    jtr = jnp.array([1e-3, -2e-3], dtype)
    side = jnp.zeros(2, jnp.int32)
    for s in (1.0, 1e-6):
        dec = decrement(jtj * s**2, jtr * s**2, side)
        np.testing.assert_allclose(float(dec) / s**2, float(decrement(jtj, jtr, side)),
                                   rtol=1e-3)
