"""The model catalogue (no JAX) against the registry (JAX): the snapshot that
``brdffit models`` and the option checks read is the registry's own description."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from brdffit import models
from brdffit.models import catalogue

pytestmark = pytest.mark.contract


def test_snapshot_is_the_registry():
    assert catalogue.SNAPSHOT.read_text() == catalogue.snapshot(models.BUILTIN), (
        "brdffit/models/catalogue.json is out of date: "
        "run python -m brdffit.models --write-catalogue")
    assert models.names() == list(models.REGISTRY)  # no plugin in the test environment


def test_describe_and_check_name_need_no_jax():
    code = ("import sys, json\nfrom brdffit import models\n"
            "names = models.names()\nmodels.check_name('ggx_mono')\n"
            "models.check_name('auto', allow_auto=True)\n"
            "assert models.catalogue.n_params('ggx_mono') == 6\n"
            "print(json.dumps([names, 'jax' in sys.modules]))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    names, jax_loaded = json.loads(r.stdout)
    assert names[0] == "lambert" and "ggx2" in names and not jax_loaded


@pytest.mark.parametrize("name", ["nope", "auto", "lambert_mono", "ggx_mono_mono", ""])
def test_unknown_names_are_refused_with_the_choices(name):
    with pytest.raises(models.UnknownModelError, match="choose one of lambert, oren_nayar"):
        models.check_name(name)


def test_every_name_the_catalogue_accepts_the_registry_builds():
    for info in models.describe():
        m = models.get(info["name"])
        assert [s.name for s in m.param_specs] == [p["name"] for p in info["params"]]
        assert catalogue.n_params(info["name"]) == m.n_params
        if info["mono"]:
            mono = models.get(info["name"] + "_mono")
            assert catalogue.n_params(mono.name) == mono.n_params < m.n_params
    assert models.check_name("auto", allow_auto=True) == "auto"
