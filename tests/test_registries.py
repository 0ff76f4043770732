"""Loss, solver and export target as registered objects (issue 39): each registry
holds exactly the names the JAX-free options and the shells offer, an unknown name
is one error that lists the choices, and each loss's closed-form slope is the
derivative of its compression."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdffit.errors import FitInputError
from brdffit.export import TARGETS, ExportError, get_target
from brdffit.fitting import loss, options, problem

pytestmark = pytest.mark.unit


def test_registries_hold_the_options_names_in_their_order():
    assert tuple(loss.LOSS_REGISTRY) == options.LOSSES
    assert tuple(problem.SOLVER_REGISTRY) == options.SOLVERS
    assert options.DEFAULT_LOSS in loss.LOSS_REGISTRY
    assert options.DEFAULT_SOLVER in problem.SOLVER_REGISTRY
    for registry in (loss.LOSS_REGISTRY, problem.SOLVER_REGISTRY, TARGETS):
        assert all(name == entry.name for name, entry in registry.items())


def test_loss_attributes_keep_the_names_other_modules_read():
    assert loss.SELECTABLE == ("log", "cube_root", "linear_cos")  # selector values are data
    assert loss.LOSS_METRIC == {"log": "log_rmse", "cube_root": "cube_root_rmse",
                                "linear_cos": "rmse_cos", "render": "render_rmse"}
    assert loss.FULL_TABLE_LOSSES == loss.SELECTABLE
    assert [n for n, x in loss.LOSS_REGISTRY.items() if x.rendered] == ["render"]


def test_only_the_lm_solver_takes_its_steps_as_data():
    assert [n for n, s in problem.SOLVER_REGISTRY.items() if s.steps_as_data] == ["lm"]
    assert problem.takes_steps_as_data("lm", problem.STEP_CAP)
    assert not problem.takes_steps_as_data("lm", problem.STEP_CAP + 1)
    assert not problem.takes_steps_as_data("dogleg", 10)


def test_export_targets_describe_their_modules():
    assert tuple(TARGETS) == ("mitsuba", "gltf", "materialx")
    for target in TARGETS.values():
        # the shells list each target's models through SHADED_AS
        assert target.SHADED_AS is target.shaded_as is target.module.SHADED_AS
        assert set(target.target_models) <= set(target.shaded_as)
        assert target.media_type == target.module.MEDIA_TYPE
    assert [t.name for t in TARGETS.values() if t.glb] == ["gltf"]
    assert [t.name for t in TARGETS.values() if t.variants] == ["mitsuba"]


@pytest.mark.parametrize(("get", "error", "message"), [
    (loss.get_loss, FitInputError,
     "unknown loss 'l1'; choose one of log, cube_root, linear_cos, render"),
    (problem.get_solver, FitInputError,
     "unknown solver 'l1'; choose one of lm, optx-lm, dogleg, bfgs"),
    (get_target, ExportError, "unknown export target 'l1'; choose one of mitsuba, gltf, materialx"),
])
def test_an_unknown_name_is_one_error_that_lists_the_choices(get, error, message):
    with pytest.raises(error) as caught:
        get("l1")
    assert str(caught.value) == message
    assert caught.value.__cause__ is None and caught.value.__suppress_context__


def test_unknown_loss_in_the_loss_functions_is_the_same_error():
    with pytest.raises(FitInputError, match="unknown loss 'l1'"):
        loss.compress_values(jnp.ones(3), "l1")


# 0, the toe of each curve, the working range and a highlight far above the exposure
X = np.array([0.0, 1e-9, 1e-6, 1e-3, 0.02, 0.5, 1.0, 3.0, 40.0, 1e3])


@pytest.mark.parametrize("name", list(loss.LOSS_REGISTRY))
def test_each_loss_slope_is_the_derivative_of_its_compression(name):
    spec = loss.get_loss(name)
    with jax.enable_x64(True):
        x = jnp.asarray(X, jnp.float64)
        auto = jax.vmap(jax.grad(lambda v: spec.compress(v)))(x)
        slope = jnp.broadcast_to(spec.slope(x), x.shape)
        assert np.all(np.isfinite(np.asarray(slope)))
        np.testing.assert_allclose(np.asarray(slope), np.asarray(auto), rtol=1e-10)
        # and the selected form's slope is the same function
        if spec.selectable:
            selector = jnp.asarray(loss.SELECTABLE.index(name))
            np.testing.assert_array_equal(
                np.asarray(loss.compress_slope(x, loss.SELECTED, selector)), np.asarray(slope))


@pytest.mark.parametrize("name", list(loss.LOSS_REGISTRY))
def test_each_loss_uncompress_inverts_its_compression(name):
    spec = loss.get_loss(name)
    exposure = 2.5 if spec.rendered else None  # compress sees the exposed value
    with jax.enable_x64(True):
        x = jnp.asarray(X[X >= 1e-3], jnp.float64)
        t = spec.compress(x * (exposure or 1.0))
        np.testing.assert_allclose(np.asarray(spec.uncompress(t, exposure)), np.asarray(x),
                                   rtol=1e-7)


def test_numpy_and_jax_compressions_agree():
    """``target_xp`` chooses where a table's targets are compressed: either module
    computes the same function."""
    with jax.enable_x64(True):
        for spec in loss.LOSS_REGISTRY.values():
            np.testing.assert_allclose(np.asarray(spec.compress(jnp.asarray(X))),
                                       spec.compress(X, np), rtol=1e-13, atol=1e-15)
