"""Compiled fits kept on disk (brdffit.executables): a second process runs them
without tracing and gets the very same fit; a damaged file is compiled again; a
plugin's code, whose changes the fingerprint cannot see, is never kept."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from brdffit import executables, models, runtime
from brdffit.fitting import sphere

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.contract

PROBE = r"""
import json, logging, sys
logging.basicConfig(level=logging.DEBUG, stream=sys.stderr, format="%(message)s")
for name in ("jax", "absl"):
    logging.getLogger(name).setLevel(logging.WARNING)
from brdffit import fit
from data_synth.synth import Component, make_table

table, _ = make_table([Component("ggx", {"kd": [0.2, 0.1, 0.05], "ks": [0.5, 0.5, 0.5],
                                       "alpha": 0.08, "f0": 0.04})])
out = {}
for solver in sys.argv[1:] or ["lm"]:
    r = fit(table, "ggx", samples=2048, seed=0, solver=solver)
    out[solver] = {"params": r.params, "error": r.error, "result": r.result,
                   "uncertainty": r.uncertainty}
from brdffit import executables
compiled = [e.name for e in executables.events if e.how == "compiled"]
lapack = "scipy.linalg.cython_lapack" in sys.modules  # JAX's LAPACK kernels made ready
print(json.dumps({"fits": out, "compiled": compiled, "lapack": lapack}))
"""


def _run(cache: Path, *solvers: str) -> tuple[dict, str]:
    """The probe in a new process whose brdffit cache is ``cache``: its stored
    executables are ``cache``'s own, JAX's compile cache (``cache/jax``) the test
    session's (a link), so that what is compiled is what the session has compiled
    already (seconds each) and what is stored or loaded is brdffit's alone."""
    env = {k: v for k, v in os.environ.items() if k != "XDG_CACHE_HOME"}
    env["BRDFFIT_CACHE_DIR"] = str(cache)
    session = runtime.cache_dir()
    if session is not None and not (cache / "jax").exists():
        os.makedirs(os.path.join(session, "jax"), exist_ok=True)
        cache.mkdir(parents=True, exist_ok=True)
        (cache / "jax").symlink_to(os.path.abspath(os.path.join(session, "jax")))
    r = subprocess.run([sys.executable, "-c", PROBE, *solvers], capture_output=True,
                       text=True, timeout=600, cwd=ROOT, env=env)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1]), r.stderr


def _stored(cache: Path) -> list[Path]:
    return sorted((cache / "executables").glob("*/*.xla"))


@pytest.mark.system  # two processes, the first compiling into an empty cache, ~20 s
def test_a_second_process_runs_the_stored_fit_and_gets_the_same_result(tmp_path):
    cache = tmp_path / "cache"
    first, log1 = _run(cache)
    files = _stored(cache)
    assert any(f.name.startswith("solve_batch-") for f in files), files
    assert "loaded compiled" not in log1

    second, log2 = _run(cache)
    assert "loaded compiled brdffit.fitting.problem.solve_batch" in log2
    assert second["fits"] == first["fits"]  # to the last bit: the same executable and data
    # brdffit's lm solve calls no LAPACK: loading it skips their kernels' set-up, which
    # imports SciPy's LAPACK (0.13-0.18 s; executables.calls_lapack)
    assert not second["lapack"]

    # damaged files (a disk error, a killed writer) are compiled again and replaced
    for f in files:
        f.write_bytes(b"not an executable")
    third, log3 = _run(cache)
    assert third["fits"] == first["fits"]
    assert "not loaded" in log3
    assert all(f.stat().st_size > 100 for f in _stored(cache))


@pytest.mark.system  # processes compiling into an empty cache, ~20 s
def test_solves_that_call_lapack_run_from_their_stored_programs(tmp_path):
    # optimistix's Levenberg-Marquardt and dogleg solve with QR (LAPACK): their
    # stored programs crashed the next process (a segmentation fault on first run)
    solvers = ("optx-lm", "dogleg")
    first, _ = _run(tmp_path, *solvers)
    second, log = _run(tmp_path, *solvers)
    assert log.count("loaded compiled brdffit.fitting.problem.solve_batch") >= len(solvers)
    assert second["lapack"]
    # loaded, not compiled again (a compile lowers a QR, which would hide the crash)
    assert not [n for n in second["compiled"] if n.endswith("solve_batch")], second["compiled"]
    # equal to rounding: the table is fitted exactly, where the last bits of a dogleg
    # solve differed between processes on a loaded machine (the note of issue 25)
    _assert_close(second["fits"], first["fits"])


def test_a_program_calls_lapack_where_its_payload_names_a_routine():
    """A loaded program that names JAX's LAPACK kernels gets them made ready first
    (their QR solves crashed otherwise, above); one that names none does not (a
    stored lm fit: the first test above)."""
    import jax
    import jax.numpy as jnp
    from jax.experimental import serialize_executable

    def payload(f):
        return serialize_executable.serialize(jax.jit(f).lower(jnp.zeros((4, 3))).compile())[0]

    assert executables.calls_lapack(payload(lambda a: jnp.linalg.qr(a)[0].sum()))
    assert not executables.calls_lapack(payload(lambda a: (a * a).sum()))


def _assert_close(got, want, path=""):
    """Equal structures, numbers within 1e-9 relative or 1e-12 absolute (the
    uncertainty of an exact fit is rounding: ~1e-17)."""
    if isinstance(want, dict):
        assert got.keys() == want.keys(), path
        for k in want:
            _assert_close(got[k], want[k], f"{path}/{k}")
    elif isinstance(want, list):
        assert len(got) == len(want), path
        for i, (g, w) in enumerate(zip(got, want, strict=True)):
            _assert_close(g, w, f"{path}[{i}]")
    elif isinstance(want, float):
        assert got == pytest.approx(want, rel=1e-9, abs=1e-12), path
    else:
        assert got == want, path


EVALUATE_PROBE = r"""
import json, logging, sys
logging.basicConfig(level=logging.INFO, stream=sys.stderr)
import numpy as np
import jax.numpy as jnp
from brdffit import executables, models, runtime
from brdffit.fitting import sphere
with runtime.float64():  # a fit's context: JAX's persistent cache under the cache dir
    jnp.sin(jnp.arange(3.0)).block_until_ready()  # JAX has used its cache in this process
    rng = np.random.default_rng(0)
    wi, wo = (v / np.linalg.norm(v, axis=-1, keepdims=True)
              for v in np.abs(rng.normal(size=(2, 32, 3))))
    out = sphere.evaluate(models.get("lambert"), {"kd": np.array([0.5, 0.4, 0.3])}, wi, wo)
print(json.dumps({"how": [e.how for e in executables.events], "sum": float(out.sum())}))
"""


@pytest.mark.slow  # 5 s warm (a second process): make test runs it
def test_a_program_kept_in_a_process_that_used_jax_cache_loads_later(tmp_path):
    """A program kept on disk is compiled afresh even where JAX's persistent cache
    holds it (JAX serves it from there without its machine code): the kept file is
    lost, the next process compiles it again while JAX's cache has it, and the one
    after loads what that one kept, instead of finding it broken."""
    env = {**os.environ, "BRDFFIT_CACHE_DIR": str(tmp_path)}

    def run() -> tuple[dict, str]:
        r = subprocess.run([sys.executable, "-c", EVALUATE_PROBE], capture_output=True,
                           text=True, timeout=120, cwd=ROOT, env=env)
        assert r.returncode == 0, r.stderr
        return json.loads(r.stdout.strip().splitlines()[-1]), r.stderr

    first, _ = run()
    assert first["how"] == ["compiled"]
    assert any((tmp_path / "jax").iterdir())  # JAX's own cache holds it too
    for f in _stored(tmp_path):
        f.unlink()
    second, _ = run()
    assert second["how"] == ["compiled"]
    third, log = run()
    assert third["how"] == ["loaded"], log[-3000:]
    assert "does not run" not in log
    assert third["sum"] == first["sum"]


def _fresh(fn):
    """The decorated function as a new process sees it: nothing in memory."""
    return executables.jit(fn.__wrapped__, compiled_forms=fn.compiled_forms)


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("BRDFFIT_CACHE_DIR", str(tmp_path))
    return tmp_path


def _directions(n=64):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2]) + 0.1
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_arguments_key_the_stored_executables(cache, caplog):
    wi, wo = _directions()
    ggx = models.get("ggx")
    params = {"kd": np.array([0.2, 0.1, 0.05]), "ks": np.array([0.5, 0.5, 0.5]),
              "alpha": np.array(0.1), "f0": np.array(0.04)}
    evaluate = _fresh(sphere.evaluate)
    expected = np.asarray(evaluate(ggx, params, wi, wo))
    evaluate(ggx, params, wi[:32], wo[:32])  # another shape: another executable
    evaluate(models.get("beckmann"), params, wi, wo)  # another model: another one
    assert len(_stored(cache)) == 3

    with caplog.at_level(logging.DEBUG, logger="brdffit"):
        again = np.asarray(_fresh(sphere.evaluate)(ggx, params, wi, wo))
    assert "loaded compiled brdffit.fitting.sphere.evaluate" in caplog.text
    np.testing.assert_array_equal(again, expected)
    assert len(_stored(cache)) == 3


def test_a_damaged_file_is_read_once_then_replaced(cache, caplog):
    wi, wo = _directions()
    kd = {"kd": np.array([0.5, 0.4, 0.3])}
    expected = np.asarray(_fresh(sphere.evaluate)(models.get("lambert"), kd, wi, wo))
    (path,) = _stored(cache)
    path.write_bytes(b"not an executable")
    with caplog.at_level(logging.INFO, logger="brdffit"):
        again = np.asarray(_fresh(sphere.evaluate)(models.get("lambert"), kd, wi, wo))
    np.testing.assert_array_equal(again, expected)
    assert caplog.text.count("not loaded") == 1, caplog.text
    assert path.stat().st_size > 100  # compiled again and kept


def test_plugin_code_is_compiled_in_memory_only(cache):
    evaluate = _fresh(sphere.evaluate)
    wi, wo = _directions()

    class Plugin(models.get("lambert").__class__):  # a class from outside brdffit
        pass

    out = np.asarray(evaluate(Plugin(), {"kd": np.array([0.5, 0.5, 0.5])}, wi, wo))
    np.testing.assert_allclose(out, 0.5 / np.pi)
    assert _stored(cache) == []


def test_no_cache_directory_keeps_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("BRDFFIT_CACHE_DIR", "")
    wi, wo = _directions()
    out = np.asarray(_fresh(sphere.evaluate)(models.get("lambert"),
                                              {"kd": np.array([0.5, 0.5, 0.5])}, wi, wo))
    np.testing.assert_allclose(out, 0.5 / np.pi)
    assert not any(tmp_path.iterdir())


def test_threads_compile_each_program_once_and_side_by_side_programs_all_run(cache):
    """Auto's candidates and a fit's report make programs ready from several threads:
    threads asking for the same program wait for one compile of it; different
    programs (here: two models, and one already on disk) all come back right."""
    from concurrent.futures import ThreadPoolExecutor

    wi, wo = _directions()
    lambert, ggx = models.get("lambert"), models.get("ggx")
    p_lambert = {"kd": np.array([0.5, 0.4, 0.3])}
    p_ggx = {"kd": np.array([0.2, 0.1, 0.05]), "ks": np.array([0.5, 0.5, 0.5]),
             "alpha": np.array(0.1), "f0": np.array(0.04)}
    # on disk, to be loaded: made in float64, as the threads below ask for it (the
    # precision is part of a program's key; the main thread's depends on what ran
    # before in this process)
    runtime.in_float64(_fresh(sphere.evaluate))(lambert, p_lambert, wi[:16], wo[:16])
    expected = {name: np.asarray(sphere.evaluate.__wrapped__(m, p, wi, wo))
                for name, m, p in (("lambert", lambert, p_lambert), ("ggx", ggx, p_ggx))}
    expected_small = np.asarray(sphere.evaluate.__wrapped__(lambert, p_lambert, wi[:16], wo[:16]))

    evaluate = _fresh(sphere.evaluate)
    before = len(executables.events)
    calls = [("lambert", lambert, p_lambert, wi, wo)] * 4 + [("ggx", ggx, p_ggx, wi, wo)] * 4 \
        + [("small", lambert, p_lambert, wi[:16], wo[:16])] * 4
    in_threads = runtime.in_float64(evaluate)  # float64 is a per-thread setting in JAX
    with ThreadPoolExecutor(6) as pool:
        runs = [(name, pool.submit(in_threads, m, p, a, b)) for name, m, p, a, b in calls]
        for name, run in runs:
            want = expected_small if name == "small" else expected[name]
            np.testing.assert_allclose(np.asarray(run.result()), want, rtol=1e-12)
    made = [(e.name, e.how) for e in executables.events[before:]]
    assert sorted(how for _, how in made) == ["compiled", "compiled", "loaded"], made


def test_programs_compile_with_brdffits_xla_options_and_without_those_xla_refuses(
        cache, monkeypatch, caplog):
    """brdffit's programs compile with :data:`executables.CPU_COMPILER_OPTIONS` (this
    XLA takes them all); an option that an XLA does not know costs its speed only:
    the program compiles without it, says so once, and gives the same values."""
    wi, wo = _directions()
    ggx = models.get("ggx")
    params = {"kd": np.array([0.2, 0.1, 0.05]), "ks": np.array([0.5, 0.5, 0.5]),
              "alpha": np.array(0.1), "f0": np.array(0.04)}
    monkeypatch.setattr(executables, "_options_refused", set())
    expected = np.asarray(_fresh(sphere.evaluate)(ggx, params, wi, wo))
    assert executables._options_refused == set()  # none refused

    monkeypatch.setenv("BRDFFIT_CACHE_DIR", "")
    monkeypatch.setattr(executables, "CPU_COMPILER_OPTIONS",
                        {**executables.CPU_COMPILER_OPTIONS, "xla_cpu_no_such_option": True})
    with caplog.at_level(logging.INFO, logger="brdffit"):
        refused = np.asarray(_fresh(sphere.evaluate)(ggx, params, wi, wo))
        np.asarray(_fresh(sphere.evaluate)(ggx, params, wi[:32], wo[:32]))
    assert caplog.text.count("XLA refused compiler options") == 1
    assert "xla_cpu_no_such_option" in executables._options_refused
    np.testing.assert_allclose(refused, expected, rtol=1e-12)


AT_ONCE_PROBE = r"""
import json, os, sys, time
import numpy as np
import jax.numpy as jnp
from brdffit import executables, models, runtime
from brdffit.fitting import sphere
from brdffit.fitting.problem import constrained
rng = np.random.default_rng(0)
wi, wo = (v / np.linalg.norm(v, axis=-1, keepdims=True)
          for v in np.abs(rng.normal(size=(2, 4096, 3))))
m = models.get("ggx2")
with runtime.float64():
    params = constrained(m, np.zeros(m.n_params))  # compiled before the signal
jnp.zeros(1).block_until_ready()  # JAX started: both processes now wait for the signal
open(sys.argv[2], "w").close()
while not os.path.exists(sys.argv[1]):
    time.sleep(0.005)
with runtime.float64():
    out = sphere.evaluate(m, params, wi, wo)
print(json.dumps({"how": [e.how for e in executables.events if e.name.endswith(".evaluate")],
                  "sum": float(out.sum())}))
"""


def test_processes_starting_at_once_compile_a_program_once(tmp_path):
    """Processes that want the same program at the same moment (a batch's Dask
    workers, a service's workers on an empty cache): one compiles it, the others
    wait for its file and load it, and all get the same values."""
    env = {**os.environ, "BRDFFIT_CACHE_DIR": str(tmp_path / "cache")}
    go = tmp_path / "go"
    procs = [subprocess.Popen([sys.executable, "-c", AT_ONCE_PROBE, str(go),
                               str(tmp_path / f"ready{i}")], cwd=ROOT, env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in range(2)]
    deadline = time.monotonic() + 120
    while not all((tmp_path / f"ready{i}").exists() for i in range(2)):
        assert time.monotonic() < deadline and all(p.poll() is None for p in procs), \
            [p.communicate() for p in procs]
        time.sleep(0.01)
    go.touch()
    outs = []
    for p in procs:
        stdout, stderr = p.communicate(timeout=300)
        assert p.returncode == 0, stderr
        outs.append(json.loads(stdout.strip().splitlines()[-1]))
    assert sorted(h for o in outs for h in o["how"]) == ["compiled", "loaded"]
    assert outs[0]["sum"] == outs[1]["sum"]
