"""In auto, lobe models of one family share their compiled programs
(brdffit.models.base.share_programs),
and a member's values, gradients and fits are its own."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdffit import executables, models
from brdffit.fitting.physical import PhysicalRanges
from brdffit.models.base import (
    SharedLobe,
    share_programs,
    sharing_where_it_pays,
    with_shared_programs,
)
from brdffit.models.mono_ks import MonoKs
from tests.compiled_models import check_jit

pytestmark = pytest.mark.unit

MEMBERS = ["blinn_phong", "phong", "beckmann", "ggx", "beckmann_dielectric", "ggx_dielectric"]


def _pairs(n=4000, seed=3):
    """Random pairs over the hemisphere, grazing ones included."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2])
    v[:, : n // 10, 2] *= 1e-4  # near the horizon
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return jnp.asarray(v[0]), jnp.asarray(v[1])


def _params(model, seed=0):
    """A random point of the model's parameter space, shape parameters spread over
    their range (sharp lobes and wide ones)."""
    u = np.random.default_rng(seed).normal(scale=3.0, size=model.n_params)
    return model.constrain(jnp.asarray(u))


@check_jit  # one program per model: op by op, every primitive compiles on its own
def _values_and_gradient(m, p, u, wi, wo):
    def loss(u):
        return jnp.sum(jnp.log1p(m.eval_channels(m.constrain(u), _frame(wi, wo))))

    return m(p, wi, wo), jax.grad(loss)(u)


@pytest.mark.parametrize("name", MEMBERS)
def test_a_member_through_its_family_is_the_member(name):
    model = models.get(name)
    assert model.compiled_form() is model  # alone, its own programs
    shared = with_shared_programs(model).compiled_form()
    assert isinstance(shared, SharedLobe)
    assert shared.members[int(shared.which)] == model
    assert shared.param_specs == model.param_specs
    wi, wo = _pairs()
    for seed in range(4):
        p = _params(model, seed)
        u = jnp.asarray(model.unconstrain({k: np.asarray(v) for k, v in p.items()}))
        f_shared, g_shared = _values_and_gradient(shared, p, u, wi, wo)
        f_model, g_model = _values_and_gradient(model, p, u, wi, wo)
        np.testing.assert_allclose(f_shared, f_model, rtol=1e-13, atol=0)
        np.testing.assert_allclose(g_shared, g_model, rtol=1e-11)


def _frame(wi, wo):
    from brdffit.models.frame import shading_frame

    return shading_frame(wi, wo)


def test_a_family_is_of_one_parameter_layout_and_other_models_keep_their_own():
    families = {tuple(m.name for m in with_shared_programs(models.get(n)).compiled_form().members)
                for n in MEMBERS}
    assert families == {("blinn_phong", "phong"), ("beckmann", "ggx"),
                        ("beckmann_dielectric", "ggx_dielectric")}
    for name in ("lambert", "oren_nayar", "ggx2", "gltf_pbr", "standard_surface"):
        m = models.get(name)
        assert with_shared_programs(m) is m
        assert m.compiled_form() is m
    phong, ggx, lambert = (type(models.get(n)) for n in ("phong", "ggx", "lambert"))
    for family in ((phong, ggx), (ggx,), (lambert, ggx)):
        with pytest.raises(ValueError, match="same parameters"):
            share_programs(*family)

    class Sharper(ggx):  # another lobe under a built-in's name
        pass

    assert with_shared_programs(Sharper()).compiled_form() == Sharper()


def test_only_members_fitted_together_share():
    def sharing(names):
        return [getattr(m, "shared_programs", None)
                for m in sharing_where_it_pays([models.get(n) for n in names])]

    assert sharing(["ggx"]) == [False]  # alone: its own, smaller programs
    assert sharing(["beckmann", "ggx"]) == [True, True]
    assert sharing(["beckmann", "ggx_dielectric"]) == [False, False]  # two families
    assert sharing(["lambert", "blinn_phong", "phong", "ggx", "ggx2"]) == [
        None, True, True, False, None]
    assert sharing(["ggx", "ggx_mono"]) == [False, None]  # a wrapper keeps its base's


def test_a_request_for_several_members_fits_them_on_shared_programs(monkeypatch):
    from brdffit import request as request_module
    from brdffit.fitting import pipeline as scene_module
    from data_synth.synth import make_table

    fitted = []
    real = scene_module.fit_in_scene

    def spy(table, model, scene, **options):
        fitted.append(model)
        return real(table, model, scene, **options)

    monkeypatch.setattr(scene_module, "fit_in_scene", spy)
    table, _ = make_table("phong", {"kd": [0.2, 0.15, 0.1], "ks": [0.4, 0.3, 0.2], "n": 80.0})
    report = request_module.run(table, request_module.FitRequest.of(
        ["phong", "blinn_phong", "lambert"], samples=1024))
    assert [m.name for m in fitted] == ["phong", "blinn_phong", "lambert"]
    assert [getattr(m, "shared_programs", None) for m in fitted] == [True, True, None]
    assert sorted(report.fits) == ["blinn_phong", "lambert", "phong"]
    assert report.fits["phong"].model == "phong"


def test_wrapped_members_share_their_base_family():
    ggx = with_shared_programs(models.get("ggx"))
    for wrapped in (MonoKs(ggx), PhysicalRanges(ggx)):
        form = wrapped.compiled_form()
        assert type(form) is type(wrapped)
        assert isinstance(form.base, SharedLobe)
        assert form.param_specs == wrapped.param_specs
        wi, wo = _pairs(500)
        p = _params(wrapped, 1)
        np.testing.assert_allclose(form(p, wi, wo), wrapped(p, wi, wo), rtol=1e-13)


def test_one_program_serves_a_family_and_a_timed_one_is_the_models_own():
    @executables.jit
    def shared_eval(model, params, wi, wo):
        return model(params, wi, wo)

    @executables.jit(compiled_forms=False)
    def own_eval(model, params, wi, wo):
        return model(params, wi, wo)

    wi, wo = _pairs(256)
    ggx, beckmann = (with_shared_programs(models.get(n)) for n in ("ggx", "beckmann"))
    p = _params(ggx)
    for fn, programs in ((shared_eval, 1), (own_eval, 2)):
        before = len(executables.events)
        a, b = fn(ggx, p, wi, wo), fn(beckmann, p, wi, wo)
        compiled = [e for e in executables.events[before:] if e.how == "compiled"]
        assert len(compiled) == programs, fn
        np.testing.assert_allclose(a, ggx(p, wi, wo), rtol=1e-13)
        np.testing.assert_allclose(b, beckmann(p, wi, wo), rtol=1e-13)


FITS = r"""
import json, sys
from brdffit import executables, fit, models
from brdffit.models.base import with_shared_programs
from data_synth.synth import make_table

table, _ = make_table("ggx", {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.7, 0.6], "alpha": 0.15,
                              "f0": 0.6}, noise=0.02, seed=4)

def compiled_by(name):
    before = len(executables.events)
    r = fit(table, with_shared_programs(models.get(name)))  # as auto fits it
    names = sorted(e.name.rsplit(".", 1)[-1] for e in executables.events[before:]
                   if e.how == "compiled")
    return {"params": {k: [float(x) for x in (v if hasattr(v, "__len__") else [v])]
                       for k, v in r.params.items()},
            "log_rmse": r.error["log_rmse"], "steps": r.steps, "compiled": names}

out = {"ggx": compiled_by("ggx"), "beckmann": compiled_by("beckmann")}
executables._compiled_forms = lambda args, kwargs: (args, kwargs)  # each its own programs
out["beckmann_own"] = compiled_by("beckmann")
print(json.dumps(out))
"""


@pytest.mark.system
def test_a_family_member_fits_on_the_programs_another_compiled(tmp_path):
    """A new process fits ggx, then beckmann: beckmann's fit compiles none of the
    fit's programs (they are ggx's, shared), and equals the fit of beckmann on
    programs of its own."""
    env = {**os.environ, "BRDFFIT_CACHE_DIR": str(tmp_path)}
    r = subprocess.run([sys.executable, "-c", FITS], capture_output=True, text=True,
                       env=env, timeout=600, cwd=os.path.dirname(os.path.dirname(__file__)))
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    fit_programs = {"solve_batch", "score_starts", "_full_errors", "linearisation",
                    "_sphere_measures"}
    assert fit_programs <= set(out["ggx"]["compiled"])
    assert not fit_programs & set(out["beckmann"]["compiled"]), out["beckmann"]["compiled"]
    assert fit_programs <= set(out["beckmann_own"]["compiled"])
    shared, own = out["beckmann"], out["beckmann_own"]
    assert shared["steps"] == own["steps"]
    assert shared["log_rmse"] == pytest.approx(own["log_rmse"], rel=1e-10)
    for k, v in own["params"].items():
        np.testing.assert_allclose(shared["params"][k], v, rtol=1e-8, atol=1e-12)
