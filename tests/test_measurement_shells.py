"""Sample files through the CLI and the batch (issue 39): ``brdffit fit`` in its own
process and ``run_batch`` take an ASTM or CSV file as they take a MERL table, fit it
at its samples' own directions, and report it in each fit's ``input`` (coverage,
held-out folds); a malformed file is one line and exit 2 (the CLI), a failed table
(the batch). The service's upload: tests/test_api.py."""

from __future__ import annotations

import json

import pytest

from tests.cli_helpers import run, run_main
from tests.table_files import BAD_CSV, SAMPLED, write_astm

pytestmark = pytest.mark.system


@pytest.fixture(scope="module")
def astm_file(tmp_path_factory):
    return write_astm(tmp_path_factory.mktemp("astm") / "lab.astm", "ggx", SAMPLED)


def test_cli_fits_a_sample_file_at_its_own_directions(astm_file, tmp_path):
    r = run_main("brdffit.cli", "fit", str(astm_file), "--model", "ggx", "--samples", "4096",
            "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["schema"] == "brdffit.fit/9"
    assert out["input"]["format"] == "astm" and out["input"]["samples"] == 20_000
    assert out["input"]["fitted_at"] == "samples" and out["input"]["used"] == 4096
    assert "fitted at their own directions" in r.stderr  # said before the fit
    assert out["error"]["held_out_log_rmse"] >= 0 and out["quality"]["basis"] == "held_out"
    assert out["params"]["alpha"] == pytest.approx(SAMPLED["alpha"], rel=0.05)
    # '-': the same file from standard input (it was "-: cannot read: No such file")
    with open(astm_file, "rb") as f:
        piped = run("brdffit.cli", "fit", "-", "--model", "ggx", "--samples", "4096",
                    "--json", stdin=f)
    assert piped.returncode == 0, piped.stderr
    assert json.loads(piped.stdout)["params"] == out["params"]
    bad = tmp_path / "bad.csv"
    bad.write_text(BAD_CSV)
    r = run_main("brdffit.cli", "fit", str(bad), "--model", "ggx")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "theta_o_deg is below the horizon" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_a_batch_fits_sample_files_beside_merl_tables(astm_file, tmp_path):
    from brdffit.batch.job import run_batch
    from brdffit.batch.store import read_results
    from brdffit.request import FitRequest
    from tests.table_files import write_tables

    write_tables(tmp_path, {"ggx": ("ggx", {"kd": [0.1] * 3, "ks": [0.5] * 3, "alpha": 0.1,
                                            "f0": 0.5})})
    bad = tmp_path / "bad.csv"
    bad.write_text(BAD_CSV)
    (tmp_path / "lab.astm").write_bytes(astm_file.read_bytes())
    out = tmp_path / "r.h5"
    # the lab's folder as it is: a table, a sample list, a bad list, and the results
    # file the batch writes there (not taken as an input)
    run_batch([str(tmp_path)], FitRequest.of("ggx", samples=2048, starts=1), out,
              workers=0, progress=False)
    tables = {t["name"]: t for t in read_results(out)["tables"]}
    assert sorted(tables) == ["bad.csv", "ggx", "lab.astm"]
    lab = tables["lab.astm"]["fits"]["ggx"]["fit"]
    assert lab["input"]["format"] == "astm" and lab["input"]["samples"] == 20_000
    assert lab["input"]["fitted_at"] == "samples" and "held_out_log_rmse" in lab["error"]
    assert tables["ggx"]["fits"]["ggx"]["fit"]["input"] is None
    assert "below the horizon" in json.dumps(tables["bad.csv"])
