"""brdffit in a fresh process leaves the caller's JAX alone: no float64 switched on,
no file written on import; the cache directory appears on the first fit, where the
settings say, and a fit is in double precision all the same."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.contract

PROBE = r"""
import json, os, sys
import jax
before = bool(jax.config.jax_enable_x64)
import brdffit
from brdffit import fit, merl, models
from data_synth.synth import Component, make_table

after_import = bool(jax.config.jax_enable_x64)
cache = os.environ.get("BRDFFIT_CACHE_DIR")
existed_after_import = os.path.exists(cache) if cache else None
table, _ = make_table([Component("ggx", {"kd": [0.2, 0.2, 0.2], "ks": [0.5, 0.5, 0.5],
                                       "alpha": 0.05, "f0": 0.04})])
r = fit(table, sys.argv[1], samples=4096, seed=0)
from brdffit.io import grid
grid.wait_until_stored()  # the bin grid's file is written beside the fit
print(json.dumps({
    "x64_before": before, "x64_after_import": after_import,
    "x64_after_fit": bool(jax.config.jax_enable_x64),
    "cache_after_import": existed_after_import,
    "cache_files": sorted(os.listdir(cache)) if cache and os.path.exists(cache) else None,
    "alpha": r.params.get("alpha"), "converged": r.converged, "log_rmse": r.log_rmse,
    "jax_cache_dir": jax.config.jax_compilation_cache_dir,
}))
"""


def _probe(env: dict, model: str = "ggx") -> dict:
    r = subprocess.run([sys.executable, "-c", PROBE, model], capture_output=True, text=True,
                       timeout=300, cwd=ROOT, env=env)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


def _env(**changes) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("BRDFFIT_CACHE_DIR", "XDG_CACHE_HOME")}
    env.update(changes)
    return env


@pytest.mark.system  # a fresh process with an empty cache: a real compile, ~10 s
def test_fit_leaves_x64_off_and_writes_the_cache_on_first_use(tmp_path):
    cache = tmp_path / "cache"
    out = _probe(_env(BRDFFIT_CACHE_DIR=str(cache)))
    assert out["x64_before"] is False
    assert out["x64_after_import"] is False and out["x64_after_fit"] is False
    assert out["cache_after_import"] is False, "import must write nothing"
    assert "jax" in out["cache_files"] and "merl-grid-v2.npz" in out["cache_files"]
    assert any(f.startswith("sphere-integral-v") for f in out["cache_files"])
    assert out["jax_cache_dir"] == str(cache / "jax")
    # the fit ran in float64 although the caller's JAX is float32: a near-mirror
    # alpha comes back to many digits
    assert out["converged"] and out["alpha"] == pytest.approx(0.05, rel=1e-6)


@pytest.mark.system  # fresh processes that compile into empty caches, ~16 s
def test_cache_off_and_xdg_location(tmp_path):
    # where the cache goes does not depend on the model: lambert compiles fastest
    off = _probe(_env(BRDFFIT_CACHE_DIR="", HOME=str(tmp_path / "home")), "lambert")
    assert off["jax_cache_dir"] is None and off["converged"]
    assert not (tmp_path / "home").exists()
    xdg = _probe(_env(XDG_CACHE_HOME=str(tmp_path / "xdg")), "lambert")
    assert (tmp_path / "xdg" / "brdffit" / "merl-grid-v2.npz").exists()
    assert xdg["jax_cache_dir"] == str(tmp_path / "xdg" / "brdffit" / "jax")
