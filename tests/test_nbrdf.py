"""Real materials rebuilt from the shipped neural BRDFs (data_synth.nbrdf).

The check is independent of data_synth.nbrdf: the network is rebuilt from its
Keras JSON config (layer sizes, activations, the trailing exp(y) - 1), its
weights read with h5py from an extracted copy, and its input formed from the bin
centre's directions (tests/reference_merl.py) rather than from bin angles.
"""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile

import h5py
import numpy as np
import pytest

from brdffit.io import merl
from data_synth import nbrdf
from tests.reference_merl import SCALE, bin_centre_directions

pytestmark = pytest.mark.system


def _reference_network(name, tmp_path):
    with zipfile.ZipFile(nbrdf.WEIGHTS_ZIP) as z:
        z.extract(f"merl_nbrdf/{name}.h5", tmp_path)
        config = json.loads(z.read(f"merl_nbrdf/{name}.json"))
    layers = [c for c in config["config"]["layers"] if c["class_name"] == "Dense"]
    with h5py.File(tmp_path / "merl_nbrdf" / f"{name}.h5", "r") as f:
        weights = [
            (f[c["config"]["name"]][c["config"]["name"]]["kernel:0"][()],
             f[c["config"]["name"]][c["config"]["name"]]["bias:0"][()],
             c["config"]["activation"])
            for c in layers
        ]
    assert [w[0].shape for w in weights] == [(6, 21), (21, 21), (21, 3)]
    assert config["config"]["layers"][-1]["class_name"] == "Lambda"

    def run(x):
        for kernel, bias, act in weights:
            x = x @ kernel.astype(np.float64) + bias
            x = np.maximum(x, 0) if act == "relu" else x
        return np.expm1(x)

    return run


def _network_input(wi, wo):
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    th = np.arccos(np.clip(h[:, 2], -1, 1))
    c, s = np.cos(-th), np.sin(-th)  # rotate wi by -theta_h about y (phi_h = 0 here)
    d = np.stack([c * wi[:, 0] + s * wi[:, 2], wi[:, 1], -s * wi[:, 0] + c * wi[:, 2]], 1)
    return np.concatenate([h, d], axis=1)


@pytest.mark.parametrize("name", ["gold-metallic-paint", "blue-fabric"])
def test_table_matches_an_independent_evaluation(name, tmp_path):
    out = tmp_path / f"{name}.binary"
    proc = subprocess.run(
        [sys.executable, "-m", "data_synth", "nbrdf", name, "-o", str(out)],
        capture_output=True, text=True,
    )
    assert proc.returncode == 0, proc.stderr
    table = merl.read(out)
    raw = np.fromfile(out, dtype="<f8", offset=12).reshape(3, -1)

    wi, wo = bin_centre_directions()
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    assert np.all(raw[:, ~above] < 0), "below the horizon is written unmeasured"
    assert np.array_equal(table.mask.ravel(), above)

    pick = np.random.default_rng(1).choice(np.flatnonzero(above), 5000, replace=False)
    expected = np.maximum(_reference_network(name, tmp_path)(_network_input(wi[pick], wo[pick])), 0)
    got = table.rgb.reshape(3, -1)[:, pick].T
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-9)
    # the file stores raw values: physical value / MERL's channel scale
    np.testing.assert_allclose(raw[:, pick].T * np.array(SCALE), expected, rtol=1e-5, atol=1e-9)


def test_all_hundred_materials_ship():
    names = nbrdf.material_names()
    assert len(names) == 100
    assert {"chrome", "gold-metallic-paint", "blue-fabric", "white-paint"} <= set(names)


def test_unknown_material_is_a_clear_error(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "data_synth", "nbrdf", "unobtainium", "-o", str(tmp_path / "x")],
        capture_output=True, text=True,
    )
    assert proc.returncode == 2
    assert "unknown material 'unobtainium'" in proc.stderr and "Traceback" not in proc.stderr
