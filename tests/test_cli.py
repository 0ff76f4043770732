"""`brdffit fit` / `brdffit models` as a user runs them: real processes."""

from __future__ import annotations

import json
import struct
import subprocess
import sys

import pytest

from tests.cli_helpers import run, run_main
from tests.truths import FIT_JSON_KEYS, TRUTH, assert_params_close

pytestmark = pytest.mark.system


@pytest.fixture(scope="module")
def ggx_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "ggx.binary"
    params = [
        f"--param={k}={','.join(map(str, v)) if isinstance(v, list) else v}"
        for k, v in TRUTH["ggx"].items()
    ]
    r = run_main("data_synth", str(path), "--model", "ggx", *params)
    assert r.returncode == 0, r.stderr
    return path


def test_fit_json_is_one_object_with_the_schema(ggx_file):
    r = run("brdffit.cli", "fit", str(ggx_file), "--model", "ggx", "--json")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 1
    d = json.loads(lines[0])
    for key in FIT_JSON_KEYS:
        assert key in d, key
    assert d["table"] == str(ggx_file) and d["model"] == "ggx"
    assert_params_close(d["params"], TRUTH["ggx"], rel=0.02)
    assert "log_rmse" in d["error"]


def test_fit_human_summary(ggx_file):
    r = run_main("brdffit.cli", "fit", str(ggx_file), "--model", "beckmann")
    assert r.returncode == 0, r.stderr
    assert "beckmann fit" in r.stdout and "alpha" in r.stdout and "log_rmse" in r.stdout


@pytest.mark.parametrize(
    "content, message",
    [
        (b"", "empty file"),
        (b"not a table at all\n", "text file"),
        (struct.pack("<3i", 90, 90, 180) + b"\0" * 100, "truncated"),
        (struct.pack("<3i", -1, 90, 180), "not positive"),
    ],
)
def test_malformed_table_is_one_line_no_traceback(tmp_path, content, message):
    p = tmp_path / "bad.binary"
    p.write_bytes(content)
    r = run_main("brdffit.cli", "fit", str(p))
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and message in err[0] and str(p) in err[0]


def test_unknown_model_and_missing_file(tmp_path, ggx_file):
    r = run_main("brdffit.cli", "fit", str(ggx_file), "--model", "cook_torrance")
    assert r.returncode == 2 and "unknown model" in r.stderr and "Traceback" not in r.stderr
    r = run_main("brdffit.cli", "fit", str(tmp_path / "missing.binary"))
    assert r.returncode == 2 and "cannot read" in r.stderr


def test_an_empty_item_in_a_list_of_models_is_refused_not_dropped(tmp_path, ggx_file):
    """``ggx,,lambert`` (a name lost to a typo, or an empty variable) was read as
    ggx,lambert: refused wherever a command line takes a list of models, naming the
    flag, before the table is read."""
    for argv, flag in (
            (["fit", str(ggx_file), "--model", "ggx,,lambert"], "--model 'ggx,,lambert'"),
            (["fit", str(ggx_file), "--model", "auto", "--candidates", "ggx,"],
             "--candidates 'ggx,'"),
            (["batch", str(ggx_file), "--models", ",ggx", "--out", str(tmp_path / "b.h5")],
             "--models ',ggx'"),
            (["warmup", "--models", "lambert,,ggx"], "--models 'lambert,,ggx'")):
        r = run_main("brdffit.cli", *argv)  # argparse's refusal of a flag's value
        code, err = r.returncode, r.stderr
        assert code == 2, (argv, err)
        assert (f"{flag} has an empty item (two commas in a row, or one at an end): separate "
                "the names by single commas") in err, err
    assert not (tmp_path / "b.h5").exists()


def test_a_plots_folder_that_cannot_be_made_is_refused_before_the_fit(tmp_path, ggx_file):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    r = run_main("brdffit.cli", "fit", str(ggx_file), "--model", "ggx", "--plots",
            str(blocker / "plots"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"--plots {blocker / 'plots'}: cannot make the folder (Not a directory)" in r.stderr
    assert "ggx fit" not in r.stdout  # nothing was fitted first
    r = run_main("brdffit.cli", "fit", str(ggx_file), "--model", "ggx", "--plots", str(blocker))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"--plots {blocker}: a file, not a folder" in r.stderr  # not "File exists"


def test_models_lists_every_model_with_ranges():
    r = run("brdffit.cli", "models")
    assert r.returncode == 0
    for name in TRUTH:
        assert name in r.stdout
    assert "alpha" in r.stdout and "[0.001, 2]" in r.stdout
    assert "also ggx_mono (6 values)" in r.stdout  # a registry entry too (docs/models.md)
    assert "lambert_mono" not in r.stdout
    # a long parameter name keeps its model's columns in line
    assert "    specular_roughness [0.0316228, 1] (log)   specular_roughness" in r.stdout
    assert "    base_color         [0, 1]" in r.stdout
    d = json.loads(run_main("brdffit.cli", "models", "--json").stdout)
    assert {m["name"] for m in d} >= set(TRUTH)


def test_a_reader_that_goes_away_is_no_error():
    """`brdffit models --json | head -c 1`: the reader closes the pipe; brdffit stops
    quietly (no 'Broken pipe' message, no traceback) with the shell's SIGPIPE status."""
    proc = subprocess.Popen([sys.executable, "-m", "brdffit.cli", "models", "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # before it writes anything
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 141 and err.decode() == "", err.decode()


def test_a_selection_option_with_a_fixed_model_is_said_not_ignored(ggx_file):
    r = run_main("brdffit.cli", "fit", str(ggx_file), "--model", "ggx", "--tolerance", "0.01")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "tolerance 0.01" in r.stderr and "ignored" in r.stderr and "model auto" in r.stderr


def test_a_fit_that_compiles_says_so_once_and_the_next_run_does_not(ggx_file, tmp_path,
                                                                    monkeypatch):
    """A first use (an empty cache) takes seconds of compiling: one line on stderr says
    why and where the result is kept; the next run loads it and says nothing; with
    caching off, the line says nothing is kept. stdout stays one JSON object."""
    monkeypatch.setenv("BRDFFIT_CACHE_DIR", str(tmp_path / "cache"))
    first = run("brdffit.cli", "fit", str(ggx_file), "--model", "lambert", "--json")
    assert first.returncode == 0, first.stderr
    said = [ln for ln in first.stderr.splitlines() if "compiling" in ln]
    assert said == [f"brdffit: first use of these options on this machine: compiling "
                    f"(seconds; kept in {tmp_path / 'cache'} for the next run)"], first.stderr
    assert json.loads(first.stdout)["model"] == "lambert"
    again = run("brdffit.cli", "fit", str(ggx_file), "--model", "lambert", "--json")
    assert again.returncode == 0 and "compiling" not in again.stderr, again.stderr
    assert json.loads(again.stdout) == {**json.loads(first.stdout),
                                        "time_s": json.loads(again.stdout)["time_s"]}
    monkeypatch.setenv("BRDFFIT_CACHE_DIR", "")
    off = run("brdffit.cli", "fit", str(ggx_file), "--model", "lambert", "--json")
    assert off.returncode == 0, off.stderr
    assert "brdffit: compiling (seconds; not kept: BRDFFIT_CACHE_DIR is empty)" in off.stderr, \
        off.stderr


def test_warmup_keeps_the_fits_for_the_next_process(tmp_path, monkeypatch):
    """`brdffit warmup` compiles a model's fit into the cache it is given; a second
    process finds every program there and compiles none."""
    monkeypatch.setenv("BRDFFIT_CACHE_DIR", str(tmp_path / "cache"))
    first = run("brdffit.cli", "warmup", "--models", "lambert")
    assert first.returncode == 0, first.stderr
    assert f"brdffit warmup: cache {tmp_path / 'cache'} (what it holds" in first.stderr
    line = next(ln for ln in first.stderr.splitlines() if "lambert" in ln and "compiled" in ln)
    assert int(line.split(" compiled")[0].split()[-1]) > 0, first.stderr
    assert list((tmp_path / "cache" / "executables").glob("*/solve_batch-*.xla"))
    again = run("brdffit.cli", "warmup", "--models", "lambert")
    assert again.returncode == 0, again.stderr
    assert " 0 compiled" in again.stderr, again.stderr
    assert "(all loaded from the cache: nothing to compile)" in again.stderr, again.stderr
    bad = run_main("brdffit.cli", "warmup", "--models", "no_such_model")  # refused first
    assert bad.returncode == 2 and "no_such_model" in bad.stderr


def test_fit_help_names_every_format_the_readers_take():
    """The table's help listed ASTM, CSV/TSV and HDF5 while the readers also take .mat,
    .npz and .xlsx: it is made from the readers' registry, every suffix in it."""
    from brdffit.io.readers import READERS

    r = run_main("brdffit.cli", "fit", "--help")
    assert r.returncode == 0, r.stderr
    text = " ".join(r.stdout.split())  # argparse's line breaks undone
    table = text.split(" table the measured file", 1)[1].split(" options:", 1)[0]
    for suffix in READERS:
        assert suffix in table, (suffix, table)
    for words in ("MERL", "ASTM E1392", "CSV", "HDF5", "MATLAB", "NumPy", "Excel"):
        assert words in table, (words, table)


def test_auto_names_the_command_line_flag_for_a_grey_specular(tmp_path):
    """auto's reason on a grey specular said "mono_ks=True fits it", the library's
    keyword: the command line says its own flag."""
    path = tmp_path / "grey.binary"
    r = run_main("data_synth", str(path), "--model", "ggx", "--param=kd=0.2,0.1,0.05",
                 "--param=ks=0.5,0.5,0.5", "--param=alpha=0.15", "--param=f0=0.6")
    assert r.returncode == 0, r.stderr
    r = run_main("brdffit.cli", "fit", str(path), "--model", "auto", "--candidates", "ggx",
                 "--samples", "2048")
    assert r.returncode == 0, r.stderr
    assert "a monochrome ks would do (6 values instead of 8; --mono-ks fits it)." in r.stdout, \
        r.stdout
    assert "mono_ks=True" not in r.stdout


def test_a_physical_fit_says_so_and_what_its_bounds_cost(ggx_file):
    """--physical printed the header of any fit ("ggx fit (log loss)") and nothing of the
    bounds: the header says the fit is bounded, and a line the bounds' cost (against the
    unconstrained fit's log_rmse), the largest albedo and which bounds are active."""
    import dataclasses

    from brdffit.cli.fit import format_result
    from brdffit.fitting.result import FitResult

    r = run_main("brdffit.cli", "fit", str(ggx_file), "--model", "ggx", "--physical",
                 "--samples", "2048")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert "ggx fit (log loss, physically bounded)" in lines[0], lines[0]
    (bounds,) = [ln for ln in lines if ln.startswith("  physical bounds")]
    assert bounds.startswith("  physical bounds (directional albedo <= 1, reflectances <= 1): "
                             "none active, the unconstrained fit meets them (log_rmse "), bounds
    plain = run_main("brdffit.cli", "fit", str(ggx_file), "--model", "ggx", "--samples", "2048",
                     "--json")
    free = FitResult.from_dict(json.loads(plain.stdout))
    assert "physical" not in format_result(free)  # an unbounded fit says nothing of bounds
    bounded = dataclasses.replace(free, physical={
        "unconstrained_log_rmse": 0.0124, "log_rmse": 0.0130,
        "relative_cost": 0.0130 / 0.0124 - 1, "albedo_max_before": [1.08, 0.9, 0.5],
        "albedo_max_before_theta_deg": 89.0, "albedo_max_after": [0.9979, 0.8, 0.4],
        "albedo_max_after_theta_deg": 89.0, "scale": 1.0, "unconstrained_result": "successful",
        "active": ["range: ks[R] <= 1", "energy: albedo[R] <= 1 (largest 0.9979 at 89 deg)"],
        "unconstrained_params": free.params})
    text = format_result(bounded).splitlines()
    at = next(i for i, ln in enumerate(text) if ln.startswith("  physical bounds"))
    assert text[at] == ("  physical bounds (directional albedo <= 1, reflectances <= 1): "
                        "log_rmse 0.013 against the unconstrained fit's 0.0124 (+4.8%); "
                        "largest albedo 0.9979 at 89 deg (unconstrained 1.08 at 89 deg)")
    assert text[at + 1] == ("    active: range: ks[R] <= 1; energy: albedo[R] <= 1 (largest "
                            "0.9979 at 89 deg)")


def test_the_compile_notice_says_when_the_programs_kept_are_another_brdffit_s(tmp_path,
                                                                           monkeypatch):
    """A cache whose programs were compiled by another brdffit (its code edited, or
    another JAX: another fingerprint directory) and none by this one: the compile is
    no "first use of these options on this machine", and says why it happens."""
    import contextlib
    import io

    from brdffit.cli.fit import say_compiling_once

    cache = tmp_path / "cache"
    monkeypatch.setenv("BRDFFIT_CACHE_DIR", str(cache))
    other = cache / "executables" / ("0" * 24)
    other.mkdir(parents=True)
    (other / "solve_batch-0.xla").write_bytes(b"")

    def said() -> str:
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            say_compiling_once()("brdffit.fitting.problem.solve_batch", True)
        return err.getvalue()

    assert said() == (f"brdffit: compiling (seconds; brdffit or JAX changed since the programs "
                      f"kept in {cache} were compiled; kept there for the next run)\n")
    # once this brdffit keeps programs of its own, a compile is of options new to it, or
    # not used since the change
    from brdffit import executables

    (executables._directory() / "solve_batch-1.xla").write_bytes(b"")
    assert said() == (f"brdffit: first use of these options since brdffit or JAX last "
                      f"changed: compiling (seconds; kept in {cache} for the next run)\n")
    # (an empty cache: "first use of these options on this machine", test above)
