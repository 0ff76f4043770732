"""The default fits' programs shipped lowered (brdffit.exported): current with the
sources, used by a new process with an empty cache instead of tracing, and the same
fit to the last bit; passed over where they are stale."""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from brdffit import build_programs, exported

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.contract


def test_the_shipped_programs_are_current():
    """A change to a module the programs' code imports makes them stale: this fails
    until `make programs` has made them afresh."""
    assert build_programs.check() == 0, (
        "brdffit/programs are stale: run `make programs` and commit brdffit/programs")
    assert exported.usable()  # what a fit asks, from the index alone
    assert len(list(exported.DIRECTORY.glob("*" + exported.SUFFIX))) >= 40


def _jitted_modules() -> set[Path]:
    """brdffit's modules that define a function under ``executables.jit``."""
    found = set()
    for path in (ROOT / "brdffit").rglob("*.py"):
        tree = ast.parse(path.read_bytes())
        for node in ast.walk(tree):
            for d in getattr(node, "decorator_list", []):
                target = d.func if isinstance(d, ast.Call) else d
                if isinstance(target, ast.Attribute) and target.attr == "jit" and \
                        getattr(target.value, "id", "") == "executables":
                    found.add(path.resolve())
    return found


def test_the_digest_covers_every_programs_code():
    files = {exported.PACKAGE / f for f in build_programs.source_files()}
    jitted = _jitted_modules()
    assert jitted and jitted <= files, sorted(map(str, jitted - files))
    # every built-in model's code, and what they import
    for name in ("ggx", "ggx2", "oren_nayar", "gltf_iridescence", "microfacet", "base"):
        assert exported.PACKAGE / "models" / f"{name}.py" in files
    # auto's flow, which decides the set of programs a first auto runs
    assert exported.PACKAGE / "selection.py" in files
    # not the shells: a change there leaves the programs current
    for shell in ("cli/__init__.py", "batch/__init__.py", "client.py", "build_programs.py"):
        assert exported.PACKAGE / shell not in files


def test_stale_programs_are_passed_over(tmp_path, monkeypatch):
    import jax.numpy as jnp

    name = next(exported.DIRECTORY.glob("*" + exported.SUFFIX)).name[:-len(exported.SUFFIX)]
    stale = tmp_path / "INDEX"
    lines = exported.INDEX.read_text().splitlines()
    stale.write_text("\n".join(["0123456789abcdef01234567", *lines[1:]]) + "\n")
    monkeypatch.setattr(exported, "INDEX", stale)
    exported.usable.cache_clear()
    try:
        assert exported.lowered(name, [jnp.zeros(3)]) is None
        assert build_programs.check() == 1
    finally:
        monkeypatch.undo()
        exported.usable.cache_clear()


PROBE = r"""
import json, sys
from brdffit import executables, exported, fit
if sys.argv[1] == "traced":
    exported.usable = lambda: False
from data_synth import make_table
# the table brdffit warmup fits: the default options' shapes, those shipped
table, _ = make_table("ggx", {"kd": [0.12, 0.08, 0.05], "ks": [0.9, 0.8, 0.6],
                              "alpha": 0.12, "f0": 0.7}, noise=0.03, missing=0.05)
r = fit(table, "ggx")
print(json.dumps({"params": r.params, "error": r.error, "steps": r.steps,
                  "uncertainty": r.uncertainty,
                  "lowering": [e.lowering for e in executables.events if e.how == "compiled"]}))
"""


@pytest.mark.system  # two new processes compiling a first fit side by side, ~10 s
def test_a_new_process_compiles_the_shipped_programs_and_fits_the_same(tmp_path):
    runs = {}
    for how in ("shipped", "traced"):
        env = {**os.environ, "BRDFFIT_CACHE_DIR": str(tmp_path / how)}
        runs[how] = subprocess.Popen([sys.executable, "-c", PROBE, how], cwd=ROOT, env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out = {}
    for how, p in runs.items():
        stdout, stderr = p.communicate(timeout=600)
        assert p.returncode == 0, stderr
        out[how] = json.loads(stdout.strip().splitlines()[-1])
    shipped, traced = out["shipped"], out["traced"]
    # every program of a default fit comes lowered: nothing of brdffit's is traced
    assert shipped["lowering"] and set(shipped["lowering"]) == {"shipped"}, shipped["lowering"]
    assert set(traced["lowering"]) == {"traced"}
    shipped.pop("lowering"), traced.pop("lowering")
    assert shipped == traced  # the same programs: the same fit to the last bit
