"""Absurd table values: huge, denormal, all zero, one hot bin. Each is a clear
refusal (MerlFormatError: one line and exit 2 in the CLI, a failed table in a batch)
or an honest fit whose every metric is finite, never ``converged`` with an infinite
error; and every JSON brdffit writes parses with a strict parser (no NaN, Infinity).
(The service's side of both: tests/test_api.py.)"""

from __future__ import annotations

import functools
import json
import math
from decimal import Decimal

import numpy as np
import pytest

from brdffit import FitResult, MerlFormatError, fit, jsonout, models
from brdffit.batch.store import BatchStore, read_attrs, read_results
from brdffit.batch.tasks import FitOptions, FitRecord, TableReadRecord
from brdffit.cli import main as cli_main
from brdffit.fitting.problem import full_table_metrics
from brdffit.fitting.sampling import bin_weights, usable_bins
from brdffit.io import merl
from brdffit.io.merl import MAX_VALUE, MIN_PEAK, SCALE, MerlTable
from data_synth import make_table
from data_synth.synth import write_table
from tests.cli_helpers import run_main

pytestmark = pytest.mark.unit

GGX = {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.8, 0.8], "alpha": 0.2, "f0": 0.6}
HOT = (10, 20, 30)  # a bin above the horizon (theta_h ~1 deg, theta_d ~20 deg)
FAST = ["--samples", "2048", "--starts", "1"]


def strict_loads(text: str):
    def refuse(constant):
        raise AssertionError(f"{constant} in JSON")

    return json.loads(text, parse_constant=refuse)


@functools.cache
def ggx_raw() -> np.ndarray:
    """The raw file values (3, 90, 90, 180) of a GGX table; -1 where unmeasured."""
    t, _ = make_table("ggx", GGX)
    return np.where(t.mask, t.rgb / SCALE[:, None, None, None], -1.0)


def _measured(raw):
    return np.all(raw >= 0, axis=0)


def one_bin_1e300():
    raw = ggx_raw().copy()
    raw[(slice(None), *HOT)] = 1e300
    return raw


def every_bin(value):
    raw = ggx_raw()
    return np.where(np.broadcast_to(_measured(raw), raw.shape), value, -1.0)


def hot_bin(value):
    raw = every_bin(0.0)
    raw[(slice(None), *HOT)] = value
    return raw


def denormal_bins():
    """A real table with 1000 of its measured bins at raw 5e-324 (0 once scaled)."""
    raw = ggx_raw().copy()
    flat = raw.reshape(3, -1)
    flat[:, np.flatnonzero(_measured(raw).ravel())[::1000][:1000]] = 5e-324
    return raw


def to_bytes(raw: np.ndarray) -> bytes:
    return np.asarray(merl.SHAPE, "<i4").tobytes() + np.ascontiguousarray(raw, "<f8").tobytes()


N_MEASURED = int(np.count_nonzero(_measured(ggx_raw())))

#: case -> (raw values, words the refusal must contain)
REFUSED = {
    "one bin at 1e300": (one_bin_1e300, ["1 bin above 1e+12 1/sr", "raw 1e+300"]),
    "every bin at 1e300": (lambda: every_bin(1e300),
                           [f"{N_MEASURED:,} bins above 1e+12 1/sr", "raw 1e+300"]),
    "hot bin at 1e300 in zeros": (lambda: hot_bin(1e300), ["1 bin above 1e+12"]),
    "every bin denormal": (lambda: every_bin(5e-324),
                           ["brightest measured bin is 0 1/sr", "4.94e-324", "blank table"]),
    "every bin zero": (lambda: every_bin(0.0),
                       ["brightest measured bin is 0 1/sr", "raw value 0", "blank table"]),
}

#: case -> raw values of a table that is fitted, honestly
FITTED = {
    "denormal bins among real ones": denormal_bins,
}
#: case -> raw values of a table that the reader takes and the fit refuses: nothing but a
#: corrupt bin to fit (they were fitted 'good', black against black, at 100 dB)
BLANK_BUT_A_SPIKE = {
    "one hot bin in zeros": lambda: hot_bin(1000.0),
    "one hot bin near the bound": lambda: hot_bin(0.5 * MAX_VALUE / SCALE[2]),
}


def assert_honest(r: FitResult) -> None:
    """Every number finite; so a converged fit never carries an infinite error."""
    assert set(r.error) >= {"log_rmse", "rmse_cos", "rel_peak_error", "sample_log_rmse"}
    for name, v in r.error.items():
        assert math.isfinite(v), (name, v, r.result)
    for name, v in r.params.items():
        assert np.all(np.isfinite(v)), (name, v)
    d = strict_loads(r.to_json())
    assert all(isinstance(v, float) for v in d["error"].values())


# -- the library -------------------------------------------------------------------------


@pytest.mark.parametrize("case", list(REFUSED))
def test_absurd_tables_are_refused_naming_count_and_value(case):
    make, words = REFUSED[case]
    with pytest.raises(MerlFormatError) as e:
        merl.from_bytes(to_bytes(make()), source=f"{case}.binary")
    message = str(e.value)
    assert message.startswith(f"{case}.binary: ") and "\n" not in message
    for w in words:
        assert w in message, message


@pytest.mark.parametrize("case", list(REFUSED))
def test_from_values_refuses_what_the_reader_refuses(case):
    raw = REFUSED[case][0]()
    with pytest.raises(MerlFormatError, match="above 1e\\+12|blank table"):
        MerlTable.from_values(raw * SCALE[:, None, None, None], _measured(raw))


def test_bounds_are_inclusive_and_a_table_with_nothing_measured_is_refused():
    rgb = np.full((3, *merl.SHAPE), 0.1)
    rgb[0, HOT[0], HOT[1], HOT[2]] = MAX_VALUE
    assert MerlTable.from_values(rgb).rgb.max() == MAX_VALUE
    rgb[0, HOT[0], HOT[1], HOT[2]] = MAX_VALUE * 1.001
    with pytest.raises(MerlFormatError, match="1 bin above"):
        MerlTable.from_values(rgb)
    dim = np.full((3, *merl.SHAPE), 0.5 * MIN_PEAK)
    with pytest.raises(MerlFormatError, match="blank table"):
        MerlTable.from_values(dim)
    dim[1, 0, 0, 0] = MIN_PEAK
    assert MerlTable.from_values(dim).n_measured == merl.N_BINS
    with pytest.raises(MerlFormatError, match="no measured bin"):
        MerlTable.from_values(rgb, mask=np.zeros(merl.SHAPE, bool))


@pytest.mark.parametrize("case", list(FITTED))
@pytest.mark.parametrize("model", ["lambert", "ggx"])
def test_odd_but_physical_tables_fit_honestly(case, model):
    table = merl.from_bytes(to_bytes(FITTED[case]()), source=case)
    r = fit(table, model, samples=4096)
    assert_honest(r)
    # 1000 dark bins among 1.1M: still the table's own parameters
    assert r.converged
    if model == "ggx":
        assert r.params["alpha"] == pytest.approx(GGX["alpha"], rel=0.02)
        np.testing.assert_allclose(r.params["ks"], GGX["ks"], rtol=0.02)


@pytest.mark.parametrize("case", list(BLANK_BUT_A_SPIKE))
def test_a_hot_bin_in_zeros_is_read_and_refused_as_blank_by_the_fit(case):
    from brdffit.errors import FitInputError

    table = merl.from_bytes(to_bytes(BLANK_BUT_A_SPIKE[case]()), source=case)
    with pytest.raises(FitInputError, match=f"{case}: no reflectance to fit but 1 isolated "
                                            "spike"):
        fit(table, "lambert", samples=4096)


def test_float32_overflow_of_the_full_table_error_falls_back_to_float64():
    table = merl.from_bytes(to_bytes(ggx_raw()))
    m = models.get("ggx")
    w = bin_weights(usable_bins(table).usable)
    # ks 1e30: (f cos)^2 ~1e60 overflows float32, not float64
    u = m.unconstrain(m.check_params({**GGX, "ks": [1e30] * 3}))
    in32 = full_table_metrics(table, m, u, w)
    in64 = full_table_metrics(table, m, u, w, dtype=np.float64)
    assert all(math.isfinite(v) for v in in32.values()), in32
    for k in in64:
        assert in32[k] == pytest.approx(in64[k], rel=1e-6)
    assert in32["rmse_cos"] > 1e28


# -- strict JSON --------------------------------------------------------------------------


def test_strict_replaces_nonfinite_floats_and_keeps_their_keys():
    value = {"a": math.nan, "b": [math.inf, 1.5, np.float32(2.0)], "c": (np.float64(-np.inf),),
             "d": {"e": np.int64(3), "f": "text", "g": None, "h": True}}
    assert jsonout.strict(value) == {"a": None, "b": [None, 1.5, 2.0], "c": [None],
                                     "d": {"e": 3, "f": "text", "g": None, "h": True}}
    assert strict_loads(jsonout.dumps(value)) == jsonout.strict(value)
    # What strict() does not know still cannot reach the output as NaN.
    with pytest.raises(ValueError, match="JSON compliant"):
        jsonout.dumps({"x": Decimal("NaN")}, default=float)


def test_fit_result_json_writes_a_missing_metric_as_null():
    r = FitResult(model="lambert", params={"kd": [0.1, 0.2, 0.3]},
                  error={"log_rmse": 0.5, "sample_log_rmse": math.nan, "rmse_cos": math.inf},
                  converged=False, result="nonfinite", steps=0, time_s=0.1, samples={})
    d = strict_loads(r.to_json())
    assert d["error"] == {"log_rmse": 0.5, "sample_log_rmse": None, "rmse_cos": None}
    assert math.isnan(r.error["sample_log_rmse"])  # the Python value is left as it is


def test_data_synth_sidecar_is_strict(tmp_path):
    table = merl.from_bytes(to_bytes(hot_bin(1000.0)))
    sidecar = write_table(str(tmp_path / "t.binary"), table, {"noise": math.nan, "n": 1})
    with open(sidecar) as f:
        assert strict_loads(f.read()) == {"noise": None, "n": 1}


def _fit_record(path: str, error: dict) -> FitRecord:
    fit_dict = {"model": "lambert", "params": {"kd": [0.5, 0.4, 0.3]}, "error": error,
                "converged": False, "result": "nonfinite", "steps": 3, "time_s": 0.1,
                "starts": 1, "samples": {"used": 1, "usable": 1, "measured": 1, "dropped": {
                    "unmeasured": 0, "nonfinite": 0, "below_horizon": 0}}}
    return FitRecord(path=path, model="lambert", sha256="1", options=FitOptions().fit_keywords(),
                     status="ok", fit=fit_dict)


def test_batch_journal_is_strict_and_a_null_metric_is_nan_in_hdf5(tmp_path):
    out = tmp_path / "r.h5"
    error = {"log_rmse": math.nan, "sample_log_rmse": math.inf, "rmse_cos": 0.25}
    with BatchStore(out) as store:  # no checkpoint: the journal is all there is
        store.add(TableReadRecord(path="/t.binary", status="ok", sha256="1"),
                  [_fit_record("/t.binary", error)])
    with open(str(out) + ".journal") as f:
        lines = [strict_loads(line) for line in f]
    assert lines[1]["fit"]["error"] == {"log_rmse": None, "sample_log_rmse": None,
                                        "rmse_cos": 0.25}
    with BatchStore(out) as store:  # a later run replays the journal
        assert store.recovered == 2
        store.checkpoint({"models": ["lambert"], "options": FitOptions().key()})
    got = read_results(out)["tables"][0]["fits"]["lambert"]["error"]
    assert got == {"log_rmse": None, "sample_log_rmse": None, "rmse_cos": 0.25}  # strict
    import h5py

    with h5py.File(out, "r") as f:  # NaN in the file itself, as HDF5 tools read it
        assert math.isnan(f["tables/t/lambert/error/log_rmse"][()])
    attrs = read_attrs(out)
    assert strict_loads(attrs["models"]) == ["lambert"]
    # the resume key: the fit keywords, but the loss and physical only when not the default
    assert strict_loads(attrs["options"]) == {k: v for k, v in FitOptions().fit_keywords().items()
                                              if k not in ("loss", "physical")}


@pytest.mark.contract  # the command line, through its main() in this process
def test_batch_report_json_is_strict_with_a_refused_table(tmp_path, capsys):
    hot, blank = tmp_path / "hot.binary", tmp_path / "blank.binary"
    hot.write_bytes(to_bytes(hot_bin(1000.0)))
    blank.write_bytes(to_bytes(every_bin(0.0)))
    out = tmp_path / "r.h5"
    code = cli_main(["batch", str(hot), str(blank), "--models", "lambert,ggx", "--out",
                     str(out), "--workers", "0", "--quiet", *FAST])
    err = capsys.readouterr().err
    assert code == 1 and "blank table" in err
    assert cli_main(["batch-report", str(out), "--json", "--no-png"]) == 0
    report = strict_loads(capsys.readouterr().out)
    tables = {t["name"]: t for t in report["tables"]}
    assert tables["blank"]["status"] == "failed" and "blank table" in tables["blank"]["message"]
    assert tables["hot"]["status"] == "ok"
    assert all(math.isfinite(v) for v in tables["hot"]["log_rmse"].values())
    assert {m["model"] for m in report["models"]} == {"lambert", "ggx"}
    for attr in ("models", "options"):
        strict_loads(read_attrs(out)[attr])
    # A model with no successful fit at all: its mean and median are NaN, null in JSON.
    only_blank = tmp_path / "blank.h5"
    assert cli_main(["batch", str(blank), "--models", "lambert", "--out", str(only_blank),
                     "--workers", "0", "--quiet", *FAST]) == 1
    capsys.readouterr()
    assert cli_main(["batch-report", str(only_blank), "--json", "--no-png"]) == 0
    summary = strict_loads(capsys.readouterr().out)["models"]
    assert summary == [{"model": "lambert", "fitted": 0, "failed": 0, "wins": 0, "mean": None,
                        "median": None, "not_converged": 0,
                        "looks": {"good": 0, "visible": 0, "poor": 0}}]


# -- the CLI, as a user runs it --------------------------------------------------------------


@pytest.mark.parametrize("case", list(REFUSED))
@pytest.mark.contract  # the command line, through its main() in this process
def test_cli_refuses_absurd_tables_in_one_line(tmp_path, case):
    make, words = REFUSED[case]
    path = tmp_path / "absurd.binary"
    path.write_bytes(to_bytes(make()))
    r = run_main("brdffit.cli", "fit", str(path), "--json")
    assert r.returncode == 2, r.stderr
    assert r.stdout == "" and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0], r.stderr
    for w in words:
        assert w in lines[0], lines[0]


def test_cli_json_writes_a_missing_metric_as_null(capsys):
    """The CLI's writer itself (a fit whose every start diverged has sample_log_rmse
    NaN; no table makes one on demand)."""
    from argparse import Namespace

    from brdffit.cli.fit import write_report
    from brdffit.request import FitReport, FitRequest

    r = FitResult(model="lambert", params={"kd": [0.1, 0.2, 0.3]},
                  error={"log_rmse": 0.5, "rmse_cos": 0.1, "rel_peak_error": 0.2,
                         "sample_log_rmse": math.nan},
                  converged=False, result="nonfinite", steps=0, time_s=0.1, samples={})
    report = FitReport(request=FitRequest.of("lambert"), fits={"lambert": r}, failed={},
                       chosen="lambert", reason="", ranking=[])
    assert write_report(Namespace(json=True, plots=None), None, report, "") == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    assert strict_loads(out)["error"]["sample_log_rmse"] is None


@pytest.mark.parametrize("model", ["lambert", "auto"])
@pytest.mark.contract  # the command line, through its main() in this process
def test_cli_json_of_a_hot_bin_fit_is_strict_and_finite(tmp_path, model):
    path = tmp_path / "hot.binary"
    raw = every_bin(1.0)  # a dim table, ~7e-4 1/sr (zeros beside it are refused as blank)
    raw[(slice(None), *HOT)] = 1000.0
    path.write_bytes(to_bytes(raw))
    r = run_main("brdffit.cli", "fit", str(path), "--model", model, "--json", *FAST)
    assert r.returncode == 0, r.stderr
    d = strict_loads(r.stdout)
    result = d  # fixed or auto: one result schema
    assert result["error"] and all(isinstance(v, float) and math.isfinite(v)
                                   for v in result["error"].values()), result["error"]
    if model == "auto":
        assert d["selection"]["chosen"] == result["model"]


def _one_corrupt_bin(table: MerlTable, at=(0, 0, 0), value=9.3e11) -> MerlTable:
    rgb = table.rgb.copy()
    rgb[(slice(None), *at)] = value
    return MerlTable(rgb, table.mask, "corrupt.binary")


def test_a_lone_corrupt_bin_is_named_in_the_notes_and_leads_what_to_try():
    """One bin at 9e11 1/sr (within the bound) made the default ggx fit ks 1e6 with
    nothing pointing at the bin: it is found (1000x every neighbour) and named."""
    base = merl.from_bytes(to_bytes(ggx_raw()), source="ggx.binary")
    assert base.isolated_spikes().shape == (0, 3)
    corrupt = _one_corrupt_bin(base)
    np.testing.assert_array_equal(corrupt.isolated_spikes(), [[0, 0, 0]])
    r = fit(corrupt, "ggx", samples=4096)
    assert_honest(r)
    said = [n for n in r.notes if "over 1,000x every measured neighbour" in n]
    assert said and "9.3e+11 1/sr at theta_h, theta_d, phi_d bin [0, 0, 0]" in said[0], r.notes
    if r.quality["verdict"] != "good":
        assert r.quality["next"][0]["try"].startswith("the table without its spikes")
    # a clean fit says nothing of spikes; neither does a bin outside what the fit used
    assert not any("every measured neighbour" in n for n in fit(base, "ggx", samples=4096).notes)


def test_a_blank_table_with_corrupt_bins_is_refused_as_blank(tmp_path):
    """Zeros everywhere but one bin of 1e6 (raw) passed the reader's blank check, which
    reads the brightest bin, and was fitted 'good' at 100 dB, black against black: the
    fit refuses it, naming the spike, in the library, the CLI and auto."""
    from brdffit.errors import FitInputError
    from brdffit.selection import select

    zeros = np.zeros((3, *merl.SHAPE))
    blank = _one_corrupt_bin(MerlTable(zeros, np.ones(merl.SHAPE, bool), "blank.binary"),
                             at=(0, 0, 5), value=1.1e3)
    with pytest.raises(FitInputError, match=r"no reflectance to fit but 1 isolated spike "
                                             r"\(the brightest 1.1e\+03 1/sr .* bin \[0, 0, 5\]"):
        fit(blank, "ggx", samples=4096)
    with pytest.raises(FitInputError, match="a blank table"):
        select(blank, ("lambert", "ggx"), samples=4096)
    path = tmp_path / "spike.binary"
    merl.write(path, blank)
    done = run_main("brdffit.cli", "fit", str(path), "--samples", "4096")
    assert done.returncode == 2 and "no reflectance to fit but 1 isolated spike" in done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
    # a table with reflectance beside its spike is fitted, the spike named (above)
    lit = _one_corrupt_bin(MerlTable(np.full((3, *merl.SHAPE), 1e-3),
                                     np.ones(merl.SHAPE, bool), "lit.binary"), value=1.1e3)
    assert fit(lit, "lambert", samples=4096).converged


@pytest.mark.parametrize("alpha", [0.001, 0.01])
def test_a_mirror_peak_is_no_spike(alpha):
    """The sharpest lobe the models hold, noise-free and noisy: its first theta_h bins
    change by far less than 1000x from one to the next."""
    for noise in (0.0, 0.05):
        table, _ = make_table("ggx", {"kd": [0.0, 0.0, 0.0], "ks": [1.0, 1.0, 1.0],
                                      "alpha": alpha, "f0": 0.9}, seed=1, noise=noise)
        assert table.isolated_spikes().shape == (0, 3)


def test_a_peak_beside_a_neighbour_with_a_channel_at_zero_is_no_spike():
    """A sparse noisy table's true peak (317 1/sr) beside its one measured neighbour,
    whose one channel noise had clipped to 0 (249, 0, 339), was named a corrupt spike
    "over 1,000x" that 0, and the first step was to delete it. Each bin is read by its
    brightest channel; a corrupt channel is still caught."""
    rgb = np.full((3, *merl.SHAPE), 0.05)
    mask = np.zeros(merl.SHAPE, bool)
    mask[1, 76, 149] = mask[1, 76, 150] = mask[40, 40, 90] = True
    rgb[:, 1, 76, 149] = (317.0, 280.0, 300.0)
    rgb[:, 1, 76, 150] = (249.0, 0.0, 339.0)
    table = MerlTable(rgb, mask, "sparse.binary")
    assert table.isolated_spikes().shape == (0, 3)
    rgb[2, 1, 76, 149] = 9.3e5  # one channel corrupt, 2,700x the neighbour's brightest
    np.testing.assert_array_equal(MerlTable(rgb, mask, "c.binary").isolated_spikes(),
                                  [[1, 76, 149]])
