"""The export's shells: ``brdffit export`` as a subprocess, and
``GET /v1/fits/{id}/exports/{target}`` on a real server through ``Client.export``;
both give what ``brdffit.export.export`` gives."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import pytest

from brdffit.client import ApiError, Client
from brdffit.export import Export, export, gltf
from brdffit.fitting.problem import table_error
from brdffit.fitting.result import FitResult
from brdffit.io import merl
from tests.api_fixtures import FAST, Server, table_bytes, write
from tests.cli_helpers import run, run_main

pytestmark = pytest.mark.system


@pytest.fixture(scope="module")
def ggx_file(tmp_path_factory):
    return write(tmp_path_factory.mktemp("tables") / "ggx.binary", table_bytes("ggx"))


@pytest.fixture(scope="module")
def fit_json(ggx_file, tmp_path_factory):
    r = run_main("brdffit.cli", "fit", str(ggx_file), "--model", "gltf_pbr", "--samples", "2048",
            "--json")
    assert r.returncode == 0, r.stderr
    path = tmp_path_factory.mktemp("fit") / "fit.json"
    path.write_text(r.stdout)
    return path


def test_cli_writes_the_files_and_reports_fidelity(fit_json, tmp_path):
    r = run("brdffit.cli", "export", str(fit_json), "--to", "gltf", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    (written,) = tmp_path.iterdir()
    assert written.name == "ggx_gltf_pbr.gltf" and str(written) in r.stdout
    want = export(FitResult.from_dict(json.loads(fit_json.read_text())), "gltf")
    assert json.loads(written.read_text()) == want.material
    # the fit's own table is still there: the export is judged against it
    assert "gltf_pbr fit as gltf_pbr (exact); to the table: log_rmse" in r.stderr
    assert "lit sphere brightness " in r.stderr and " as displayed (radiance " in r.stderr
    assert ", colour CIEDE2000 " in r.stderr

    # another measurement, named: judged against that one instead
    other = write(tmp_path / "other.binary", table_bytes("lambert"))
    r = run_main("brdffit.cli", "export", str(fit_json), "--to", "gltf", "--json",
            "--measured", str(other))
    assert r.returncode == 0, r.stderr
    out = Export.from_dict(json.loads(r.stdout))
    expected = table_error(merl.read(other), "gltf_pbr", out.target_params)["log_rmse"]
    assert out.fidelity["log_rmse_to_table"] == pytest.approx(expected, rel=1e-9)

    # (a refit's export through the CLI: test_cli_exports_a_fit_of_a_batch_results_file;
    # the class check's refits: tests/test_export_tools.py)


def test_cli_json_with_out_writes_the_files_and_glb_writes_a_binary_gltf(fit_json, tmp_path):
    """--json --out DIR writes the files too (it wrote none, silently); --glb writes one
    binary glTF instead of the .gltf."""
    from brdffit.export import gltf

    both = tmp_path / "both"
    r = run_main("brdffit.cli", "export", str(fit_json), "--to", "gltf", "--out", str(both),
                 "--json")
    assert r.returncode == 0, r.stderr
    out = Export.from_dict(json.loads(r.stdout))  # stdout is the JSON alone
    (written,) = both.iterdir()
    assert json.loads(written.read_text()) == out.material and f"wrote {written}" in r.stderr
    binary = tmp_path / "glb"
    r = run_main("brdffit.cli", "export", str(fit_json), "--to", "gltf", "--out", str(binary),
                 "--glb")
    assert r.returncode == 0, r.stderr
    (glb,) = binary.iterdir()
    assert glb.name == "ggx_gltf_pbr.glb" and glb.read_bytes() == gltf.to_glb(out.material)
    r = run_main("brdffit.cli", "export", str(fit_json), "--to", "mitsuba", "--glb", "--out",
            str(binary))
    assert r.returncode == 2 and "needs --to gltf and --out DIR" in r.stderr


def test_cli_errors_are_one_line(fit_json, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    for args, message in (
        ([str(bad), "--to", "gltf"], "neither a fit result (JSON"),
        ([str(fit_json), "--to", "blender"], "invalid choice: 'blender'"),
        ([str(fit_json), "--to", "gltf", "--target-model", "ggx"],
         f"gltf carries {', '.join(gltf.TARGET_MODELS)}, not 'ggx'"),
        ([str(fit_json), "--to", "mitsuba", "--viewer", "threejs"],
         "--viewer is for --to gltf (spec, threejs, blender); mitsuba and materialx have "
         "their renderer's own shading"),
        ([str(fit_json), "--to", "gltf", "--measured", str(tmp_path / "none.binary")],
         "No such file"),
        # the path and what is wrong, not Python's "[Errno 2] ...: 'path'"
        ([str(tmp_path / "missing.json"), "--to", "gltf"],
         f"brdffit: error: {tmp_path / 'missing.json'}: no such file or directory"),
        ([str(tmp_path), "--to", "gltf"], f"brdffit: error: {tmp_path}: is a directory"),
        # refused before the export, naming the flag
        ([str(fit_json), "--to", "gltf", "--out", str(bad / "sub")],
         f"--out {bad / 'sub'}: cannot make the folder (Not a directory)"),
    ):
        r = run_main("brdffit.cli", "export", *args)
        assert r.returncode == 2 and message in r.stderr, r.stderr
        assert "Traceback" not in r.stderr
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"schema": "brdffit.fit/0", "model": "ggx"}))
    r = run_main("brdffit.cli", "export", str(other), "--to", "gltf")
    assert r.returncode == 2 and "not a fit result" in r.stderr and "Traceback" not in r.stderr
    # a result without its keys: which ones, not a constructor's complaint
    partial = json.loads(fit_json.read_text())
    for key in ("error", "converged"):
        del partial[key]
    other.write_text(json.dumps(partial))
    r = run_main("brdffit.cli", "export", str(other), "--to", "gltf")
    assert r.returncode == 2 and "not a fit result: no error, converged (" in r.stderr, r.stderr
    assert "__init__" not in r.stderr


def test_cli_viewer_with_another_target_is_refused_before_the_export(fit_json):
    """--viewer with --to mitsuba was refused after "exporting to mitsuba ...", in words
    that read as the glTF export refusing it: refused first, in the flags' words."""
    for target, viewer in (("mitsuba", "threejs"), ("materialx", "blender"),
                           ("mitsuba", "spec")):
        r = run_main("brdffit.cli", "export", str(fit_json), "--to", target, "--viewer", viewer)
        assert r.returncode == 2 and r.stderr == (
            "brdffit: error: --viewer is for --to gltf (spec, threejs, blender); mitsuba and "
            "materialx have their renderer's own shading\n"), r.stderr


def test_cli_stdout_is_one_document_for_each_target(fit_json):
    """`brdffit export FIT --to T > file` is one document its parser reads: Mitsuba's
    printed its RGB and its spectral scene back to back ("junk after document
    element"). stdout is the first of the files, the one for Mitsuba's RGB variants;
    stderr names the others, which --out writes."""
    from xml.etree import ElementTree

    r = run_main("brdffit.cli", "export", str(fit_json), "--to", "mitsuba")
    assert r.returncode == 0, r.stderr
    assert ElementTree.fromstring(r.stdout).tag == "scene"
    assert r.stdout.count("<scene") == 1
    assert ("brdffit: standard output holds ggx_gltf_pbr.xml alone; --out DIR writes "
            "ggx_gltf_pbr_spectral.xml too") in r.stderr, r.stderr
    r = run_main("brdffit.cli", "export", str(fit_json), "--to", "gltf")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["asset"]["version"] == "2.0"
    assert "standard output holds" not in r.stderr  # the one file: nothing left out
    r = run_main("brdffit.cli", "export", str(fit_json), "--to", "materialx")
    assert r.returncode == 0, r.stderr
    assert ElementTree.fromstring(r.stdout).tag == "materialx"


def test_cli_reads_a_fit_json_with_a_bom_and_names_one_that_is_not_utf8(fit_json, tmp_path):
    """A fit JSON saved by an editor with a UTF-8 byte-order mark is read; a file of
    other bytes is named, and said not to be a fit JSON (the codec's message, "'utf-8'
    codec can't decode byte ...", named no file)."""
    bom = tmp_path / "bom.json"
    bom.write_bytes(b"\xef\xbb\xbf" + fit_json.read_bytes())
    r = run_main("brdffit.cli", "export", str(bom), "--to", "gltf", "--json")
    assert r.returncode == 0, r.stderr
    assert Export.from_dict(json.loads(r.stdout)).target == "gltf"
    latin = tmp_path / "latin.json"
    latin.write_bytes(b'{"model": "gr\xfcn"}')
    r = run_main("brdffit.cli", "export", str(latin), "--to", "gltf")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert (f"brdffit: error: {latin}: not a brdffit fit JSON (byte 0xfc at offset 13 is not "
            "UTF-8 text); give the file brdffit fit --json wrote") in r.stderr, r.stderr


@pytest.fixture(scope="module")
def batch_store(tmp_path_factory):
    """A real batch run (``brdffit batch`` in its own process) on two real materials."""
    from data_synth import nbrdf

    root = tmp_path_factory.mktemp("batch")
    paths = [nbrdf.cached_table(name, str(root)) for name in ("gold-metallic-paint", "pink-felt")]
    out = root / "results.h5"
    r = run("brdffit.cli", "batch", *paths, "--models", "ggx,rough_conductor", "--out", str(out),
            "--workers", "0", "--samples", "4096", "--quiet", timeout=600)
    assert r.returncode == 0, r.stderr
    return out


def test_cli_exports_a_fit_of_a_batch_results_file(batch_store, tmp_path):
    from brdffit.batch.store import read_results

    stored = {t["name"]: t["fits"] for t in read_results(batch_store)["tables"]}
    gold = FitResult.from_dict(stored["gold-metallic-paint"]["rough_conductor"]["fit"])
    r = run_main("brdffit.cli", "export", str(batch_store), "--table", "gold-metallic-paint",
            "--model", "rough_conductor", "--to", "mitsuba", "--json")
    assert r.returncode == 0, r.stderr
    got = Export.from_dict(json.loads(r.stdout))
    assert got.to_dict() == json.loads(export(gold, "mitsuba").to_json())
    assert got.fidelity["exact"] and got.source_model == "rough_conductor"

    # by file name, the best fit by default, into files
    r = run_main("brdffit.cli", "export", str(batch_store), "--table", "pink-felt.binary", "--to",
            "gltf", "--target-model", "gltf_pbr", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    best = min(stored["pink-felt"].values(), key=lambda f: f["fit"]["error"]["log_rmse"])
    (written,) = tmp_path.iterdir()
    assert written.name == f"pink-felt_{best['fit']['model']}.gltf"


def test_cli_store_errors_say_what_the_file_holds(batch_store, fit_json):
    for args, message in (
        ([str(batch_store), "--to", "gltf"],
         "a batch results file; choose a table with --table (it holds gold-metallic-paint, "
         "pink-felt)"),
        ([str(batch_store), "--table", "gold", "--to", "gltf"],
         "no table 'gold'; the file holds gold-metallic-paint, pink-felt"),
        ([str(batch_store), "--table", "pink-felt", "--model", "ggx2", "--to", "gltf"],
         "table 'pink-felt' has no ggx2 fit; it has ggx, rough_conductor"),
        ([str(fit_json), "--table", "pink-felt", "--to", "gltf"],
         "a fit result holds one fit; --table and --model choose a fit of a batch results"),
    ):
        r = run_main("brdffit.cli", "export", *args)
        assert r.returncode == 2 and message in r.stderr, r.stderr
        assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with Server(tmp_path_factory.mktemp("exports"), workers=1) as s:
        yield s
        assert '" 500 ' not in s.log() and "Traceback" not in s.log(), s.log()[-5000:]


def test_api_and_client_export_a_finished_fit(server, ggx_file):
    with Client(server.url, timeout=120) as c:
        job = c.fit(c.upload(ggx_file), ["rough_conductor", "ggx"], **FAST)
        c.wait(job, timeout=300)
        conductor = c.result(job, model="rough_conductor")
        got = c.export(job, "mitsuba", model="rough_conductor")
        # the service judges the export against the job's own table
        assert got == export(conductor, "mitsuba", table=ggx_file)
        expected = table_error(merl.read(ggx_file), "rough_conductor", conductor.params)
        assert got.fidelity["exact"] and got.fidelity["log_rmse_to_table"] == pytest.approx(
            expected["log_rmse"], rel=1e-9)
        assert set(got.fidelity["sphere_colour"]) == {"brightness_stops", "colour_shift",
                                                      "displayed_brightness_stops",
                                                      "displayed_colour_shift",
                                                      "estimate_error"}
        best = c.export(job, "gltf")  # default: the best fit of the job
        assert best.source_model == c.result(job).model
        assert set(best.fidelity["viewers"]) == {"spec", "threejs", "blender"}
        # fitted for three.js's shading, on the job's table, as the library does it
        for_three = c.export(job, "gltf", viewer="threejs")
        assert for_three.fidelity["target_model"] == "gltf_threejs"
        assert for_three == export(c.result(job), "gltf", table=ggx_file, viewer="threejs")
        # made once, then served from the data dir (each GET was a worker's 5-15 s)
        kept = list(Path(server.data_dir).rglob("export-*.json"))
        assert len(kept) == 3, kept
        assert c.export(job, "gltf", viewer="threejs") == for_three
        assert c.export(job, "mitsuba", model="rough_conductor") == got
        assert len(list(Path(server.data_dir).rglob("export-*.json"))) == 3
        with pytest.raises(ApiError) as e:  # a name that is no renderer's model: not kept
            c.export(job, "gltf", target_model="../../x")
        assert e.value.status_code == 422
        assert len(list(Path(server.data_dir).rglob("export-*.json"))) == 3
        with pytest.raises(ApiError) as e:
            c.export(job, "gltf", model="lambert")
        assert e.value.status_code == 404 and "has no 'lambert' fit" in e.value.detail
        with pytest.raises(ApiError) as e:
            c.export(job, "blender")
        assert e.value.status_code == 422
        with pytest.raises(ApiError) as e:
            c.export("0" * 32, "gltf")
        assert e.value.status_code == 404 and "no fit job" in e.value.detail
    # the OpenAPI document (the client's contract) names the route and its schema
    doc = httpx.get(f"{server.url}/openapi.json", timeout=30).json()
    route = doc["paths"]["/v1/fits/{job_id}/exports/{target}"]["get"]
    assert route["operationId"] == "get_export"
    assert "ExportOut" in doc["components"]["schemas"]
