"""The quality block: every result says how it looks next to its measurement."""

from __future__ import annotations

import pytest

from brdffit import FitResult
from brdffit.fitting import pipeline as fitting
from brdffit.fitting import quality
from data_synth import make_table
from tests.truths import TRUTH

pytestmark = pytest.mark.unit


@pytest.mark.parametrize(("psnr", "shift", "word", "says"), [
    (35.0, [0.01, -0.02, 0.05], "good", "35.0 dB"),
    (28.0, [0.1, 0.0, 0.0], "good", "28.0 dB"),
    (27.9, [0.0, 0.0, 0.0], "visible", "good from 28 dB"),
    (33.0, [-0.25, -0.1, 0.0], "visible", "R channel -25%"),
    (19.9, [0.0, 0.0, 0.0], "poor", "poor below 20 dB"),
    (30.0, [0.1, 0.2, 0.63], "poor", "B channel +63%"),
    (float("nan"), [0.0, 0.0, 0.0], "poor", "no finite PSNR"),
    (30.0, [None, 0.02, 0.03], "good", "within 3%"),
])
def test_verdict_thresholds(psnr, shift, word, says):
    got, reason = quality.verdict(psnr, shift)
    assert got == word and says in reason, reason


def test_every_fit_carries_its_quality_and_it_round_trips():
    table = make_table("ggx", TRUTH["ggx"], noise=0.02, seed=1)[0]
    r = fitting.fit(table, "ggx", samples=2048)
    q = r.quality
    assert set(q) == {"render_psnr_db", "colour_shift", "verdict", "reason"}
    assert q["render_psnr_db"] == r.error["psnr_db"] and q["verdict"] == "good"
    assert all(abs(s) < 0.02 for s in q["colour_shift"])
    assert FitResult.from_dict(r.to_dict()).quality == q
    old = r.to_dict()
    del old["quality"]  # a result stored before the block existed still reads
    assert FitResult.from_dict(old).quality is None


def test_the_cli_prints_the_verdict_and_its_reason_on_one_line(tmp_path):
    from brdffit.cli.fit import format_result

    table = make_table("ggx", {**TRUTH["ggx"], "alpha": 0.35, "f0": 0.1})[0]
    r = fitting.fit(table, "blinn_phong", samples=2048)
    line = [x for x in format_result(r).splitlines() if x.strip().startswith("looks ")]
    assert len(line) == 1 and r.quality["verdict"] in line[0] and r.quality["reason"] in line[0]


@pytest.mark.parametrize("model", ["ggx", "oren_nayar"])
def test_the_fits_colour_shift_is_the_sphere_colour_error(model):
    """A fit takes its PSNR and its colour shift from one evaluation of the model
    (SphereReference.psnr_and_colour); the shift is sphere_colour_error's, made on
    its own, and the PSNR the reference's psnr."""
    import numpy as np

    from brdffit.fitting.sphere import SphereReference, sphere_colour_error
    from brdffit.models import get

    table, _ = make_table("ggx", noise=0.05, seed=3)
    r = fitting.fit(table, model, samples=2048)
    m = get(model)
    alone = sphere_colour_error(table, m, r.params)
    np.testing.assert_allclose(r.quality["colour_shift"], alone, rtol=1e-12, atol=1e-15)
    assert r.quality["colour_shift"][0] != 0.0  # a model-vs-table difference, not a copy
    assert r.error["psnr_db"] == pytest.approx(SphereReference(table).psnr(m, r.params),
                                               rel=1e-12)
