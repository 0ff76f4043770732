"""Synthetic tables: the generator's CLI, sidecars, degradations and hard-case presets."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brdffit.io import merl
from brdffit.io.grid import bin_grid
from data_synth import PRESETS, make_table
from data_synth.synth import make_preset
from tests.cli_helpers import run, run_main

pytestmark = pytest.mark.unit


def test_cli_writes_table_and_truth_sidecar(tmp_path):
    out = tmp_path / "t.binary"
    r = run(
        "data_synth",
        str(out),
        "--model",
        "ggx",
        "--param",
        "alpha=0.2",
        "--param",
        "kd=0.1,0.2,0.3",
        "--noise",
        "0.05",
        "--missing",
        "0.1",
        "--seed",
        "3",
    )
    assert r.returncode == 0, r.stderr
    truth = json.loads((tmp_path / "t.binary.json").read_text())
    assert truth["model"] == "ggx" and truth["params"]["alpha"] == 0.2
    assert truth["params"]["kd"] == [0.1, 0.2, 0.3]
    assert truth["noise"] == 0.05 and truth["missing"] == 0.1
    t = merl.read(out)
    assert t.n_measured == truth["measured_bins"]


@pytest.mark.parametrize(
    "args, message",
    [
        (["--param", "alpha"], "NAME=VALUE"),
        (["--param", "alpha=abc"], "not a number"),
        (["--param", "alpha=-1"], "alpha"),
        (["--param", "beta=1"], "unknown parameter"),
    ],
)
@pytest.mark.contract  # the command line, through its main() in this process
def test_cli_rejects_bad_params(tmp_path, args, message):
    r = run_main("data_synth", str(tmp_path / "x.binary"), "--model", "ggx", *args)
    assert r.returncode == 2
    assert message in r.stderr and "Traceback" not in r.stderr


def test_below_horizon_is_unmeasured_and_missing_fraction_holds():
    t, _ = make_table("lambert", missing=0.3, seed=1)
    above = bin_grid().above_horizon.reshape(t.mask.shape)
    assert not np.any(t.mask & ~above)
    frac = 1 - t.n_measured / above.sum()
    assert 0.28 < frac < 0.32


def test_noise_is_multiplicative_and_seeded():
    a, _ = make_table("lambert", noise=0.1, seed=5)
    b, _ = make_table("lambert", noise=0.1, seed=5)
    clean, _ = make_table("lambert")
    np.testing.assert_array_equal(a.rgb, b.rgb)
    ratio = a.rgb[:, a.mask] / clean.rgb[:, a.mask]
    assert 0.08 < ratio.std() < 0.12 and abs(ratio.mean() - 1) < 0.01


def test_copies_of_one_truth_are_independent_tables():
    """make_table keeps the last truths' rendered values: a table changed in place
    changes neither that copy nor the next table, and other params render anew."""
    from data_synth import render_values
    from data_synth.synth import Component

    clean, _ = make_table("ggx")
    with pytest.raises(ValueError, match="read-only"):  # a table is not changed in place
        clean.rgb[:] = 0.0
    again, truth = make_table("ggx")
    params = {"kd": [0.2, 0.1, 0.1], "ks": [0.5, 0.5, 0.5], "alpha": 0.3, "f0": 0.5}
    other, _ = make_table("ggx", params)
    expect = render_values([Component("ggx", truth["params"])])
    np.testing.assert_array_equal(again.rgb.reshape(3, -1), expect)
    np.testing.assert_array_equal(other.rgb.reshape(3, -1),
                                  render_values([Component("ggx", params)]))


@pytest.mark.parametrize("name", list(PRESETS))
def test_presets_make_valid_tables(name, tmp_path):
    table, truth = make_preset(name)
    assert truth["preset"] == name and table.n_measured > 1000
    assert np.all(np.isfinite(table.rgb))


@pytest.mark.contract  # the command line, through its main() in this process
def test_cli_preset_applies_noise_missing_and_params(tmp_path):
    out = tmp_path / "p.binary"
    r = run_main("data_synth", str(out), "--preset", "near-mirror", "--noise", "0.1",
            "--missing", "0.3", "--param", "alpha=0.05", "--seed", "2")
    assert r.returncode == 0, r.stderr
    truth = json.loads((tmp_path / "p.binary.json").read_text())
    assert truth["preset"] == "near-mirror"
    assert truth["noise"] == 0.1 and truth["missing"] == 0.3  # the sidecar tells the truth
    assert truth["params"]["alpha"] == 0.05 and truth["params"]["f0"] == 0.9  # rest: preset's
    t = merl.read(out)
    above = bin_grid().above_horizon.reshape(t.mask.shape)
    assert 0.28 < 1 - t.n_measured / above.sum() < 0.32  # --missing applied
    clean, _ = make_preset("near-mirror", params={"alpha": 0.05})
    keep = t.mask & (clean.rgb[0] > 1e-3)
    ratio = t.rgb[:, keep] / clean.rgb[:, keep]
    assert 0.08 < ratio.std() < 0.12  # --noise applied


def test_preset_keeps_its_own_degradations_unless_told():
    _, truth = make_preset("noisy-missing")
    assert truth["noise"] == 0.2 and truth["missing"] == 0.5
    _, truth = make_preset("noisy-missing", noise=0.0)
    assert truth["noise"] == 0.0 and truth["missing"] == 0.5


@pytest.mark.contract  # the command line, through its main() in this process
def test_cli_refuses_a_param_it_cannot_place_in_a_two_lobe_preset(tmp_path):
    r = run_main("data_synth", str(tmp_path / "x.binary"), "--preset", "two-lobes",
            "--param", "alpha=0.1")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "two-lobes" in r.stderr and "--param" in r.stderr
