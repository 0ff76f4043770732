"""Scene descriptions -> per-bin weights, scene-aware fits, and the CLI options."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from brdffit import cli
from brdffit.fitting.pipeline import fit_in_scene
from brdffit.fitting.sampling import bin_weights
from brdffit.fitting.scene import (
    WHOLE_SPHERE_WORDS,
    Scene,
    SceneError,
    full_table_error,
    read_pairs,
)
from brdffit.io import merl
from brdffit.io.angles import dirs_to_half_diff, flat_index, half_diff_to_bins
from brdffit.io.grid import bin_grid
from data_synth.synth import make_preset

pytestmark = pytest.mark.unit

FAST = {"samples": 8192, "starts": 1}


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _bin_of(wi, wo) -> int:
    return int(flat_index(*half_diff_to_bins(*dirs_to_half_diff(np.asarray(wi), np.asarray(wo)))))


# -- angle limits and presets ------------------------------------------------------------


def test_camera_normal_preset_keeps_near_normal_views():
    g = bin_grid()
    w = Scene.preset("camera-normal").bin_weight()
    assert w.shape == g.weight.shape and np.all(w >= 0)
    used = w > 0
    near = math.cos(math.radians(10.0)) - 1e-12
    # by reciprocity a bin also stands for the swapped pair: either direction may be the view
    assert np.all((g.cos_o[used] >= near) | (g.cos_i[used] >= near))
    assert not np.any(used & ~g.above_horizon)
    assert 10_000 < used.sum() < 0.2 * g.above_horizon.sum()


def test_angle_limits_and_the_whole_hemisphere():
    g = bin_grid()
    w = Scene(max_theta_i=30, max_theta_o=60).bin_weight() > 0
    ci, co = math.cos(math.radians(30)) - 1e-12, math.cos(math.radians(60)) - 1e-12
    either = ((g.cos_i >= ci) & (g.cos_o >= co)) | ((g.cos_o >= ci) & (g.cos_i >= co))
    assert w.any() and np.all(either[w])
    assert np.array_equal(Scene().bin_weight() > 0, g.above_horizon)
    with pytest.raises(SceneError, match="max_theta_i"):
        Scene(max_theta_i=0)
    with pytest.raises(SceneError, match="unknown scene preset"):
        Scene.preset("sunset")


# -- direction pairs ------------------------------------------------------------------------


def test_one_pair_without_spread_is_its_reference_bin():
    wi, wo = _unit([0.3, 0.1, 0.9]), _unit([-0.2, 0.4, 0.8])
    w = Scene(pairs=[[wi, wo]], spread=0).bin_weight()
    assert np.flatnonzero(w).tolist() == [_bin_of(wi, wo)]


def test_sampled_pairs_weight_the_loss_by_their_own_distribution():
    rng = np.random.default_rng(3)
    v = rng.normal(size=(4000, 2, 3))
    v[..., 2] = np.abs(v[..., 2]) + 0.05
    v = _unit(v)
    w = Scene(pairs=v, spread=0).bin_weight()
    counts = np.bincount([_bin_of(a, b) for a, b in v], minlength=w.size).astype(float)
    usable = bin_grid().above_horizon & (w > 0)
    # the fit's loss weight (solid angle x scene) is the pairs' histogram
    np.testing.assert_allclose(bin_weights(usable, w), counts / counts.sum(), atol=1e-12)


def test_spread_covers_a_neighbourhood_and_drops_pairs_below_the_horizon():
    good = [_unit([0.0, 0.0, 1.0]), _unit([0.5, 0.0, 0.8])]
    bad = [_unit([0.0, 0.0, 1.0]), _unit([1.0, 0.0, -0.1])]
    s = Scene(pairs=[good, bad], spread=3.0)
    assert s.dropped_pairs == 1 and len(s.pairs) == 1
    assert s.n_bins > 20 and s.bin_weight()[_bin_of(*good)] > 0
    with pytest.raises(SceneError, match="horizon"):
        Scene(pairs=[bad])


def test_lights_and_views_are_every_combination():
    s = Scene.from_dict({"lights": [[0, 0, 1], [1, 0, 1]], "views": [[0, 0, 1], [0, 1, 2]],
                         "spread": 0})
    assert len(s.pairs) == 4
    with pytest.raises(SceneError, match="both 'lights' and 'views'"):
        Scene.from_dict({"lights": [[0, 0, 1]]})
    with pytest.raises(SceneError, match="unknown scene key"):
        Scene.from_dict({"light": [[0, 0, 1]]})


def test_lights_and_views_are_kept_as_given_in_a_request():
    """141 lights with 141 views were stored as their 19,881 pairs: a 2.5 MB job record,
    and a client's body over the service's 1 MB cap for a scene it accepts. The spec
    keeps the lights and views; read back, it is the same scene, pair for pair. Pairs
    given beside them are listed as before."""
    from brdffit.request import FitRequest

    rng = np.random.default_rng(3)

    def above(n):
        d = rng.normal(size=(n, 3))
        d[:, 2] = np.abs(d[:, 2]) + 0.1
        return d.tolist()

    given = {"lights": above(141), "views": above(141), "name": "studio"}
    scene = Scene.from_dict(given)
    spec = scene.to_spec()
    assert "pairs" not in spec and len(spec["lights"]) == len(spec["views"]) == 141
    again = Scene.from_dict(spec)
    np.testing.assert_array_equal(again.pairs, scene.pairs)
    assert again == scene and again.key() == scene.key()
    body = json.dumps(FitRequest.of("ggx", scene=given).to_dict())
    assert len(body) < 30_000  # the pairs listed: ~2.5 MB
    # its key (a batch's identity of the scene) hashes the pairs listed, as before lights
    # and views were kept: a batch file made then resumes
    assert json.loads(json.dumps(scene.to_spec(pairs_listed=True)))["pairs"] == \
        np.asarray(scene.pairs).tolist()
    # made otherwise, with other pairs: the pairs it holds, not the lights' and views'
    import dataclasses

    fewer = dataclasses.replace(scene, pairs=scene.pairs[:2])
    assert fewer.lights_views is None and len(fewer.to_spec()["pairs"]) == 2
    mixed = Scene.from_dict({**given, "pairs": [[[0, 0, 1], [0, 0, 1]]]})
    assert "lights" not in mixed.to_spec() and len(mixed.to_spec()["pairs"]) == 141 * 141 + 1


# -- files ----------------------------------------------------------------------------------


def test_pair_files_npy_csv_json(tmp_path):
    pairs = _unit(np.array([[[0.1, 0.2, 0.9], [0.3, -0.1, 0.8]],
                            [[0.0, 0.5, 0.7], [0.2, 0.2, 0.9]]]))
    np.save(tmp_path / "p6.npy", pairs.reshape(-1, 6))
    np.save(tmp_path / "p23.npy", pairs)
    with open(tmp_path / "p.csv", "w") as f:
        f.write("wi_x,wi_y,wi_z,wo_x,wo_y,wo_z\n# two pairs\n")
        for p in pairs.reshape(-1, 6):
            f.write(",".join(f"{x:.17g}" for x in p) + "\n")
    for name in ("p6.npy", "p23.npy", "p.csv"):
        np.testing.assert_allclose(read_pairs(str(tmp_path / name)), pairs, atol=1e-15)
    (tmp_path / "scene.json").write_text(json.dumps(
        {"preset": "camera-normal", "max_theta_i": 45, "pairs_file": "p.csv", "spread": 0}))
    s = Scene.from_file(tmp_path / "scene.json")
    assert (s.max_theta_i, s.max_theta_o, len(s.pairs)) == (45, 10.0, 2)
    assert s.name == "camera-normal"
    s2 = Scene.from_file(tmp_path / "p23.npy")
    assert s2.pairs.shape == (2, 2, 3)


def test_bad_scene_files(tmp_path):
    (tmp_path / "s.txt").write_text("1,2,3")
    with pytest.raises(SceneError, match="json, .npy or .csv"):
        Scene.from_file(tmp_path / "s.txt")
    (tmp_path / "s.csv").write_text("0,0,1,0,0,1\n0,0,1,oops,0,1\n")
    with pytest.raises(SceneError, match="s.csv:2"):
        Scene.from_file(tmp_path / "s.csv")
    np.save(tmp_path / "s.npy", np.zeros((3, 5)))
    with pytest.raises(SceneError, match="shape"):
        Scene.from_file(tmp_path / "s.npy")
    (tmp_path / "s.json").write_text("{not json")
    with pytest.raises(SceneError, match="not valid JSON"):
        Scene.from_file(tmp_path / "s.json")
    with pytest.raises(SceneError, match="no such"):
        Scene.from_file(tmp_path / "missing.csv")
    (tmp_path / "latin1.json").write_bytes(b'{"name": "caf\xe9"}')
    with pytest.raises(SceneError, match="latin1.json: not UTF-8 text"):
        Scene.from_file(tmp_path / "latin1.json")
    (tmp_path / "latin1.csv").write_bytes(b"\xff\xfe0,0,1,0,0,1\n")
    with pytest.raises(SceneError, match="latin1.csv: not UTF-8 text"):
        Scene.from_file(tmp_path / "latin1.csv")
    (tmp_path / "folder.npy").mkdir()
    with pytest.raises(SceneError, match="folder.npy: not a file"):
        Scene.from_file(tmp_path / "folder.npy")
    # a pairs_file names a file of pairs, not another scene
    (tmp_path / "points.json").write_text('{"pairs_file": "s.json"}')
    with pytest.raises(SceneError, match="direction pairs are a .npy or .csv file, not .json"):
        Scene.from_file(tmp_path / "points.json")
    # one line each, not numpy's, json's or Python's own exceptions
    (tmp_path / "empty.npy").write_bytes(b"")
    # a complex array: numpy would drop the imaginary parts with a warning of its own
    np.save(tmp_path / "complex.npy", np.array([[[0, 0, 1], [0.1, 0, 1]]], complex))
    for name, text, says in (
            ("complex.npy", None, "complex.npy: not a numeric .npy array (its values are "
                                  "complex128, not real numbers)"),
            ("preset.json", '{"preset": [1]}', "unknown scene preset [1]"),
            ("file.json", '{"pairs_file": 5}', "scene pairs_file: the path of a .npy or .csv"),
            ("deep.json", "[" * 100_000 + "]" * 100_000, "deep.json: not a scene: JSON nested"),
            ("truth.json", '{"lights": [[true, 0, 1]], "views": [[0, 0, 1]]}',
             "scene lights: numbers, not true or false"),
            ("empty.npy", None, "empty.npy: not a numeric .npy array")):
        if text is not None:
            (tmp_path / name).write_text(text)
        with pytest.raises(SceneError, match=re.escape(says)):
            Scene.from_file(tmp_path / name)


def test_a_scene_of_more_pairs_than_binning_needs_is_refused_before_it_is_made(tmp_path):
    """3,000 lights with 3,000 views (a 142 KB file) made 9M pairs and took 2.3 GB: a
    scene holds at most MAX_PAIRS, counted before the product or the file is made."""
    from brdffit.fitting.scene import MAX_PAIRS

    side = int(MAX_PAIRS ** 0.5) + 1
    ups = np.tile([[0.1, 0.2, 1.0]], (side, 1)).tolist()
    with pytest.raises(SceneError, match=f"{side * side:,} direction pairs .*at most"):
        Scene.from_dict({"lights": ups, "views": ups})
    big = np.lib.format.open_memmap(tmp_path / "big.npy", mode="w+", dtype=np.float64,
                                    shape=(MAX_PAIRS + 1, 6))
    del big
    with pytest.raises(SceneError, match="at most"):
        Scene.from_file(tmp_path / "big.npy")


def test_a_bom_and_huge_numbers_are_directions_all_the_same(tmp_path):
    """A scene JSON saved with a byte-order mark reads (as a fit JSON does); a direction
    of 1e308s is a direction (its length overflowed, and the pair was dropped as below
    the horizon, with numpy's warning)."""
    import warnings

    (tmp_path / "bom.json").write_bytes(b"\xef\xbb\xbf" + b'{"preset": "camera-normal"}')
    assert Scene.from_file(tmp_path / "bom.json").max_theta_o == 10.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        huge = Scene(pairs=np.array([[[1e308, 1e308, 1e308], [0.0, 0.0, 1.0]]]))
        plain = Scene(pairs=np.array([[[1.0, 1.0, 1.0], [0.0, 0.0, 1.0]]]))
        np.testing.assert_array_equal(huge.bin_weight(), plain.bin_weight())
    assert huge.dropped_pairs == 0


def test_a_scene_name_is_short_text_and_angles_are_numbers():
    # a 100,000-character name made a 508 KB job record; True was read as 1 degree
    assert Scene.from_dict({"name": "n" * 255}).name == "n" * 255
    for name, words in (("n" * 256, "got 256 characters"), ("", "got 0 characters"),
                        (7, "got 7"), (None, "got None")):
        with pytest.raises(SceneError, match=f"text of 1 to 255 characters, {words}"):
            Scene.from_dict({"name": name})
    for key in ("max_theta_i", "max_theta_o", "spread"):
        with pytest.raises(SceneError, match=f"scene {key} must be in .* got True"):
            Scene.from_dict({key: True})


def test_from_options_combines_and_overrides():
    assert Scene.from_options() is None
    s = Scene.from_options(preset="camera-normal", max_theta_i=40)
    assert (s.name, s.max_theta_i, s.max_theta_o) == ("camera-normal", 40, 10.0)
    s = Scene.from_options(max_theta=20)
    assert (s.max_theta_i, s.max_theta_o) == (20, 20)
    with pytest.raises(SceneError, match="not both"):
        Scene.from_options({"preset": "camera-normal"}, preset="camera-normal")


# -- fits on a scene ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fresnel_table():
    return make_preset("strong-fresnel")[0]


def test_scene_fit_reports_scene_and_full_table_error(fresnel_table):
    scene = Scene.preset("camera-normal")
    on_scene = fit_in_scene(fresnel_table, "blinn_phong", scene, **FAST)
    everywhere = fit_in_scene(fresnel_table, "blinn_phong", None, **FAST)
    full_of_scene_fit = on_scene.full_table_error["log_rmse"]
    assert on_scene.scene["name"] == "camera-normal"
    assert on_scene.samples["usable"] == scene.n_bins
    # The scene fit is better where the scene looks, worse elsewhere: the trade.
    assert on_scene.log_rmse < 0.3 * everywhere.log_rmse
    assert full_of_scene_fit > everywhere.log_rmse
    # full_table_error of the plain fit is the plain fit's own reported error
    again = full_table_error(fresnel_table, "blinn_phong", everywhere.params)["log_rmse"]
    assert again == pytest.approx(everywhere.log_rmse, rel=1e-6)
    # the text accounts for every bin of the grid: those the scene leaves out too
    from brdffit.cli.fit import N_BINS, format_result

    (line,) = [ln for ln in format_result(on_scene).splitlines() if "bins:" in ln]
    d = on_scene.samples["dropped"]
    outside = N_BINS - on_scene.samples["usable"] - sum(d.values())
    assert outside > 0 and line.endswith(f", {outside:,} outside the scene"), line
    assert "outside the scene" not in format_result(everywhere)
    # the verdict renders every direction, where the fit weighted the scene's: it says so
    assert on_scene.quality["reason"].endswith("; " + WHOLE_SPHERE_WORDS)
    assert WHOLE_SPHERE_WORDS not in everywhere.quality["reason"]


def test_the_front_door_fits_in_a_scene(fresnel_table, tmp_path):
    from brdffit import FitInputError, fit

    by_preset = fit(fresnel_table, "blinn_phong", scene="camera-normal", **FAST)
    by_hand = fit_in_scene(fresnel_table, "blinn_phong", Scene.preset("camera-normal"), **FAST)
    assert by_preset.scene["name"] == "camera-normal"
    assert by_preset.params == by_hand.params
    assert by_preset.full_table_error == by_hand.full_table_error
    # its JSON form and a file of it give the same scene
    spec = {"preset": "camera-normal"}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(spec))
    for given in (spec, str(path), path):
        assert fit(fresnel_table, "blinn_phong", scene=given, **FAST).params == by_hand.params
    with pytest.raises(FitInputError, match="not both"):
        fit(fresnel_table, "blinn_phong", scene="camera-normal",
            bin_weight=np.ones(90 * 90 * 180), **FAST)
    from brdffit.selection import select

    for call in (fit, select):  # refused before anything is fitted
        with pytest.raises(SceneError, match="a scene is a .*got int"):
            call(fresnel_table, scene=3)
    with pytest.raises(SceneError):
        fit(fresnel_table, "blinn_phong", scene=str(tmp_path / "missing.json"), **FAST)
    with pytest.raises(SceneError, match="unknown scene preset 'camera_normal'; choose one "
                                         "of camera-normal"):
        fit(fresnel_table, "blinn_phong", scene="camera_normal", **FAST)


def test_cli_auto_with_a_scene(fresnel_table, tmp_path, capsys):
    path = str(tmp_path / "fresnel.binary")
    merl.write(path, fresnel_table)
    args = ["fit", path, "--model", "auto", "--candidates", "lambert,blinn_phong,ggx",
            "--samples", "8192", "--starts", "1"]
    assert cli.main(args + ["--scene-preset", "camera-normal"]) == 0
    out = capsys.readouterr().out
    assert "blinn_phong" in out and "chosen" in out and "camera-normal" in out
    # the chosen fit in full after the ranking, as one fit prints: its standard errors,
    # its error on the scene and on the full table, its bins
    chosen = out.split("\n\n")[-1]
    assert " fit (log loss), " in chosen.splitlines()[0] and " ± " in chosen, out
    assert "  error (scene): log_rmse " in chosen and "(full table)   scene " in chosen, out
    assert "outside the scene" in chosen and " params:" not in out, out
    assert cli.main(args + ["--json", "--tolerance", "0.001"]) == 0
    d = json.loads(capsys.readouterr().out)
    s = d["selection"]  # the chosen fit, its selection beside it (docs/results.md)
    assert s["chosen"] == d["model"] == "ggx" and s["tolerance"] == 0.001 and s["scene"] is None
    assert [r["model"] for r in s["ranking"]] == ["lambert", "blinn_phong", "ggx"]
    assert cli.main(["fit", path, "--model", "ggx", "--max-theta", "30", "--samples", "8192"]) == 0
    out = capsys.readouterr().out
    assert "(scene)" in out and "(full table)" in out
    assert cli.main(["fit", path, "--model", "auto", "--scene", str(tmp_path / "no.json")]) == 2
