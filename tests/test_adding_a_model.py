"""docs/adding-a-model.md, followed literally: the model file and the entry point are
read from the page, installed as a package would be (a dist-info with the entry
point on the path), and the model then appears in ``brdffit models``, fits from
the CLI, takes part in ``auto``, and is listed and fitted by a real server."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import httpx
import numpy as np
import pytest

from tests.api_fixtures import Server
from tests.cli_helpers import run, run_main

pytestmark = pytest.mark.system

DOC = Path(__file__).resolve().parents[1] / "docs" / "adding-a-model.md"


def _files_of_the_page() -> dict[str, str]:
    """The fenced blocks marked ``<!-- test: NAME -->`` on the page, by NAME."""
    text = DOC.read_text()
    return {m[1]: m[2] for m in re.finditer(r"<!-- test: (\S+) -->\n```\w*\n(.*?)```", text, re.S)}


@pytest.fixture(scope="module")
def plugin_path(tmp_path_factory) -> str:
    """A directory where the page's package is 'installed': its module, and a
    dist-info holding its entry points (what pip writes)."""
    files = _files_of_the_page()
    assert set(files) == {"minnaert.py", "pyproject.toml"}, "the page's files moved"
    root = tmp_path_factory.mktemp("site")
    (root / "minnaert.py").write_text(files["minnaert.py"])
    project = tomllib.loads(files["pyproject.toml"])["project"]
    info = root / f"{project['name'].replace('-', '_')}-{project['version']}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(
        f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n")
    lines = []
    for group, eps in project["entry-points"].items():
        lines.append(f"[{group}]")
        lines += [f"{name} = {target}" for name, target in eps.items()]
    (info / "entry_points.txt").write_text("\n".join(lines) + "\n")
    return str(root)


@pytest.fixture(scope="module")
def moon(tmp_path_factory, plugin_path) -> Path:
    """A table of the toy model itself (made in a process that has the plugin)."""
    path = tmp_path_factory.mktemp("moon") / "moon.binary"
    code = ("from data_synth.synth import Component, make_table\nfrom brdffit.io import merl\n"
            "t, _ = make_table([Component('minnaert', {'kd': [0.3, 0.25, 0.2], 'k': 1.6})])\n"
            f"merl.write({str(path)!r}, t)\n")
    r = _python(code, plugin_path)
    assert r.returncode == 0, r.stderr
    return path


def _env(plugin_path: str) -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(
        [plugin_path, str(DOC.parents[1]), os.environ.get("PYTHONPATH", "")])}


def _python(code: str, plugin_path: str):
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, env=_env(plugin_path))


def _cli(plugin_path: str, *args: str):
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = _env(plugin_path)["PYTHONPATH"]
    try:
        return run("brdffit.cli", *args)
    finally:
        if old is None:
            del os.environ["PYTHONPATH"]
        else:
            os.environ["PYTHONPATH"] = old


def test_the_model_is_listed_with_its_parameters(plugin_path):
    r = _cli(plugin_path, "models", "--json")
    assert r.returncode == 0, r.stderr
    info = {m["name"]: m for m in json.loads(r.stdout)}
    assert [p["name"] for p in info["minnaert"]["params"]] == ["kd", "k"]
    assert info["minnaert"]["parent"] == "lambert"
    assert "lambert" in info and "ggx" in info  # the built-ins are still there
    # without the package the name is unknown, with the choices listed
    r = run_main("brdffit.cli", "fit", "nowhere.binary", "--model", "minnaert")
    assert r.returncode == 2 and "unknown model 'minnaert'" in r.stderr


def test_the_cli_fits_it_and_auto_chooses_it(plugin_path, moon, tmp_path, monkeypatch):
    # an empty cache: what the fit compiles and keeps is said, and that the plugin's
    # own programs are compiled again in every run (a user saw "kept ... for the next
    # run" on every run of a plugin fit)
    monkeypatch.setenv("BRDFFIT_CACHE_DIR", str(tmp_path / "cache"))
    plugin_line = ("brdffit: compiling (seconds; not kept: a plugin model's programs are "
                   "compiled in every run)")
    for kept_too in (True, False):
        r = _cli(plugin_path, "fit", str(moon), "--model", "minnaert", "--json")
        assert r.returncode == 0, r.stderr
        said = sorted(ln for ln in r.stderr.splitlines() if "compiling" in ln)
        first_use = [f"brdffit: first use of these options on this machine: compiling "
                     f"(seconds; kept in {tmp_path / 'cache'} for the next run)"]
        assert said == [plugin_line, *(first_use if kept_too else [])], r.stderr
    d = json.loads(r.stdout)
    assert d["converged"] and d["params"]["k"] == pytest.approx(1.6, rel=1e-3)
    np.testing.assert_allclose(d["params"]["kd"], [0.3, 0.25, 0.2], rtol=1e-3)

    r = _cli(plugin_path, "fit", str(moon), "--model", "auto", "--candidates",
             "lambert,minnaert", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["model"] == "minnaert" and d["selection"]["chosen"] == "minnaert"


def test_the_service_lists_and_fits_it(plugin_path, moon, tmp_path):
    with Server(tmp_path / "srv", env={"PYTHONPATH": _env(plugin_path)["PYTHONPATH"]}) as srv:
        c = httpx.Client(base_url=srv.url, timeout=60)
        names = [m["name"] for m in c.get("/v1/models").json()]
        assert "minnaert" in names
        up = c.post("/v1/tables", content=moon.read_bytes(), params={"name": "moon.binary"},
                    headers={"Content-Type": "application/octet-stream"})
        assert up.status_code in (200, 201), up.text
        job = c.post("/v1/fits", json={"table_id": up.json()["id"], "model": "minnaert",
                                       "options": {"samples": 4096}})
        assert job.status_code == 202, job.text
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            got = c.get(f"/v1/fits/{job.json()['id']}").json()
            if got["status"] in ("done", "failed"):
                break
            time.sleep(0.2)
        assert got["status"] == "done", got
        assert got["result"]["model"] == "minnaert"
        assert got["result"]["params"]["k"] == pytest.approx(1.6, rel=1e-2)
