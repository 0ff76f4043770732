"""What each entry point imports: the client and ``brdffit --help`` load no JAX,
``import brdffit`` is lazy, and a missing extra is one line naming what to install.

Each check runs in a fresh interpreter: this test process has JAX loaded already.
A missing package is simulated with ``sys.modules[name] = None``, which makes both
``import name`` and ``importlib.util.find_spec(name)`` fail as if it were absent.
"""

from __future__ import annotations

import pkgutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from brdffit import cli as commands
from brdffit import extras

pytestmark = pytest.mark.contract

ROOT = Path(__file__).resolve().parents[1]


def python(code: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def without(*modules: str) -> str:
    """Code that makes ``modules`` unimportable in the interpreter it starts."""
    return "import sys\n" + "".join(f"sys.modules[{m!r}] = None\n" for m in modules)


#: Code that prints the JAX (and matplotlib) packages its interpreter has loaded.
PRINT_HEAVY = ("import sys\nprint(sorted({m.split('.')[0] for m in sys.modules} & "
               "{'jax', 'jaxlib', 'equinox', 'optimistix', 'matplotlib'}))")


def assert_loads_nothing_heavy(code: str) -> None:
    """``code`` runs in a fresh interpreter without loading JAX or matplotlib."""
    r = python(code + PRINT_HEAVY)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_client_imports_no_jax():
    assert_loads_nothing_heavy("import brdffit.client\n")


def test_the_service_front_imports_no_jax_nor_matplotlib():
    # what the server process runs for a request (tests/test_api.py checks a running one)
    assert_loads_nothing_heavy(
        "import api.main\n"
        "from brdffit.request import FitRequest\n"
        "from brdffit.selection import chosen_result\n"
        "scene = {'preset': 'camera-normal'}\n"
        "FitRequest.of('auto', samples=4096, scene=scene, tolerance=0.01).to_dict()\n"
        "FitRequest.from_dict({'models': ['ggx', 'ggx_mono'], 'options': {'loss': 'render'}})\n"
        "from api.routes.fits import FitJobRequest\n"
        "FitJobRequest(table_id='0' * 64, models='auto', scene=scene)\n"
        "r = {'model': 'ggx_mono', 'error': {'log_rmse': 0.1}}\n"
        "assert chosen_result([{'model': 'ggx', 'error': {'log_rmse': 0.1}}, r]) is r\n")


def test_import_brdffit_is_lazy_and_fit_is_there():
    r = python("import sys, brdffit\n"
               "assert 'jax' not in sys.modules, 'import brdffit loaded JAX'\n"
               "from brdffit import FitResult\n"
               "assert 'jax' not in sys.modules, 'FitResult loaded JAX'\n"
               "f = brdffit.fit\n"
               "import jax\n"
               "assert callable(f) and f.__module__ == 'brdffit.fitting.pipeline'\n"
               "assert brdffit.FitResult is brdffit.fitting.pipeline.FitResult\n"
               "assert not jax.config.jax_enable_x64, 'importing fit switched float64 on'\n"
               "assert {'fit', 'merl', 'models', 'MerlTable'} <= set(dir(brdffit))\n"
               "print('ok')")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "ok"


def test_unknown_attribute_is_an_attribute_error():
    r = python("import brdffit\ntry:\n    brdffit.no_such_thing\n"
               "except AttributeError as e:\n    print(e)")
    assert "no attribute 'no_such_thing'" in r.stdout, r.stderr


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["serve", "--help"]])
def test_cli_help_imports_no_jax(argv):
    r = python("import sys\nfrom brdffit.cli import main\n"
               f"try:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
               "print('jax' in sys.modules, file=sys.stderr)")
    assert r.stderr.strip().splitlines()[-1] == "False", r.stderr
    assert r.stdout


def test_every_command_module_is_listed():
    modules = {i.name for i in pkgutil.iter_modules(commands.__path__)} - {"__main__"}
    assert modules == {c.replace("-", "_") for c in commands.COMMANDS}
    for name in commands.COMMANDS:
        m = commands.load(name)
        assert callable(m.add_arguments) and callable(m.run), name


def test_extras_match_pyproject():
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    optional = declared["optional-dependencies"]
    assert set(extras.MODULES) <= set(optional)
    assert optional["all"] == [f"brdffit[{','.join(extras.MODULES)}]"]
    assert "brdffit[all]" in optional["test"]
    core = " ".join(declared["dependencies"])
    for extra, mods in extras.MODULES.items():
        for m in mods:  # an extra's module is the extra's, not the core's
            assert m.replace("_", "-") not in core, (extra, m)


def test_serve_without_the_service_extra_is_one_line():
    r = python(without("uvicorn") + "from brdffit.cli import main\nsys.exit(main(['serve']))")
    assert r.returncode == 2
    assert r.stderr == ("brdffit: error: brdffit serve needs the service extra: "
                        "pip install 'brdffit[service]'\n")


def test_client_without_httpx_names_the_extra():
    r = python(without("httpx") + "import brdffit.client")
    assert r.returncode == 1
    assert r.stderr.strip().splitlines()[-1] == (
        "brdffit.extras.MissingExtraError: brdffit.client needs the client extra: "
        "pip install 'brdffit[client]'")


def test_api_without_fastapi_names_the_extra():
    r = python(without("fastapi") + "import api.main")
    assert r.returncode == 1
    assert r.stderr.strip().splitlines()[-1].endswith(
        "needs the service extra: pip install 'brdffit[service]'")


def test_fit_plots_without_matplotlib_is_one_line_before_fitting(tmp_path):
    # the table does not exist: the missing extra is reported before it is read
    r = python(without("matplotlib") + "from brdffit.cli import main\n"
               f"sys.exit(main(['fit', {str(tmp_path / 'absent.binary')!r}, "
               f"'--plots', {str(tmp_path)!r}]))")
    assert r.returncode == 2
    assert r.stderr == ("brdffit: error: brdffit fit --plots needs the plots extra: "
                        "pip install 'brdffit[plots]'\n")


def test_batch_on_dask_without_it_is_one_line_and_in_process_runs(tmp_path):
    code = (without("distributed", "dask") + "from brdffit.cli import main\n"
            f"sys.exit(main(['batch', {str(tmp_path)!r}, '--models', 'lambert', "
            f"'--out', {str(tmp_path / 'r.h5')!r}, '--workers', '1', '--quiet']))")
    r = python(code)
    assert r.returncode == 2
    assert r.stderr == (
        "brdffit: error: a batch on Dask workers needs the batch extra: pip install "
        "'brdffit[batch]' (workers=0, or --workers 0, fits in this process without Dask)\n")
    assert not (tmp_path / "r.h5").exists()  # refused before the results file is made
    # --workers 0 needs no Dask (an empty directory: nothing to fit, a valid batch)
    r = python(code.replace("'--workers', '1'", "'--workers', '0'"))
    assert "batch extra" not in r.stderr


def test_batch_report_figure_without_matplotlib_is_one_line(tmp_path):
    results = str(tmp_path / "absent.h5")  # refused before the file is read
    r = python(without("matplotlib") + "from brdffit.cli import main\n"
               f"sys.exit(main(['batch-report', {results!r}]))")
    assert r.returncode == 2
    assert r.stderr == ("brdffit: error: brdffit batch-report's figure needs the plots extra: "
                        "pip install 'brdffit[plots]' (--no-png prints only)\n")
