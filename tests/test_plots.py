"""brdffit.view.plots: every kind renders a readable PNG, from the library and the CLI."""

from __future__ import annotations

import dataclasses
import io
import json

import numpy as np
import pytest
from matplotlib.image import imread

from brdffit import fit
from brdffit.cli import main as cli_main
from brdffit.fitting.pipeline import FitResult
from brdffit.io import merl
from brdffit.view import plots
from tests.api_fixtures import FAST, table

pytestmark = pytest.mark.unit


def decode_png(data: bytes) -> np.ndarray:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return imread(io.BytesIO(data), format="png")


def assert_sane_png(data: bytes) -> None:
    """A real picture: decodes, a few hundred pixels a side, not blank, not huge."""
    image = decode_png(data)
    h, w = image.shape[:2]
    assert 300 <= h <= 2200 and 500 <= w <= 2000, (h, w)  # the report page is the tallest
    assert 10_000 < len(data) < 2_000_000
    assert image[..., :3].std() > 0.05  # something is drawn


@pytest.fixture(scope="module")
def ggx():
    t = table("ggx")
    return t, fit(t, "ggx", **FAST)


@pytest.mark.parametrize("kind", plots.KINDS)
def test_each_kind_renders(ggx, kind):
    t, result = ggx
    assert_sane_png(plots.render(kind, t, result))


def test_accepts_the_json_form_of_a_result(ggx):
    t, result = ggx
    as_json = json.loads(result.to_json())
    assert plots.render("polar", t, as_json) == plots.render("polar", t, result)


def test_unknown_kind_is_refused(ggx):
    with pytest.raises(ValueError, match="unknown plot kind"):
        plots.render("histogram", *ggx)


@pytest.mark.slow
def test_sparse_table_and_null_metrics_still_plot(ggx):
    """Half the bins unmeasured shows as grey, a result with a null (NaN) metric
    still gets a title: the service stores non-finite metrics as null."""
    t, result = ggx
    keep = np.random.default_rng(0).random(t.mask.shape) < 0.5
    sparse = merl.MerlTable.from_values(t.rgb, t.mask & keep, source="sparse")
    d = result.to_dict()
    d["error"] = {**d["error"], "log_rmse": None}
    for kind in plots.KINDS:
        assert_sane_png(plots.render(kind, sparse, FitResult.from_dict(d)))


def test_evaluate_is_nan_below_the_horizon(ggx):
    _, result = ggx
    wi = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, -0.8]])
    wo = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    f = plots.evaluate(result, wi, wo)
    assert np.all(np.isfinite(f[0])) and np.all(f[0] > 0)
    assert np.all(np.isnan(f[1]))


def test_error_map_residual_matches_log_rmse(ggx):
    """The map shows the loss's own residual: its weighted RMS is log_rmse."""
    from brdffit.io.grid import bin_grid

    t = ggx[0]
    result = fit(t, "lambert", **FAST)  # a poor fit: an error well away from 0
    r = plots.bin_residuals(t, result).reshape(3, -1)
    w = np.where(np.isfinite(r[0]), bin_grid().weight, 0.0)
    w = w / w.sum()
    rmse = np.sqrt(np.nansum(w * r * r) / 3.0)
    assert result.log_rmse > 0.05
    assert rmse == pytest.approx(result.log_rmse, rel=1e-6)


@pytest.mark.slow  # a fit and every plot, through the CLI's main(): ~10 s
def test_cli_fit_writes_plots(tmp_path, capsys):
    path = tmp_path / "lambert.binary"
    merl.write(path, table("lambert"))
    out = tmp_path / "plots"
    code = cli_main(["fit", str(path), "--model", "lambert", "--json", "--samples", "2048",
                     "--starts", "1", "--plots", str(out)])
    assert code == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["model"] == "lambert"  # stdout stays pure JSON
    for kind in plots.KINDS:
        assert f"{kind}.png" in captured.err
        assert_sane_png((out / f"{kind}.png").read_bytes())
    assert not (out / "samples.png").exists()  # a sample list's alone


# -- what the pictures must show (issue 13) ---------------------------------------------


def test_spheres_share_one_exposure_so_dark_and_bright_tables_look_different():
    from data_synth import make_table

    images = []
    for kd in (0.04, 0.8):
        t, _ = make_table("lambert", {"kd": [kd] * 3})
        r = fit(t, "lambert", **FAST)
        m, f, coverage, _ = plots.sphere_images(t, r, plots.SPHERE_LIGHTS[0][1], size=48)
        images.append(plots._composite(m, coverage, np.zeros(3)))
        # the measurement and its fit are shown at the same exposure: equal images
        np.testing.assert_allclose(plots._composite(f, coverage, np.zeros(3)), images[-1],
                                   atol=0.02)
    dark, bright = (img.mean() for img in images)
    assert bright > 2.5 * dark, (dark, bright)


def test_each_verdict_light_says_at_which_exposure_the_verdict_judged_it():
    from brdffit.fitting.sphere import SphereReference
    from data_synth import make_table

    # a dark diffuse: the verdict exposes it ~4.6 stops over the picture (0.04 vs 1)
    t, _ = make_table("lambert", {"kd": [0.04] * 3})
    words = plots._verdict_exposure_words(t, plots.SPHERE_LIGHTS, 0.0)
    assert set(words) == {0, 1}  # the key and grazing lights; the back light is not judged
    ev = np.log2(SphereReference(t).exposures[0] / plots.EXPOSURE)
    assert ev > 3.0
    assert words[0] == f"\nverdict judged {round(4 * ev) / 4:+g} EV from here"
    # asked at +2 EV, the verdict's exposure is 2 stops nearer the picture's
    shifted = plots._verdict_exposure_words(t, plots.SPHERE_LIGHTS, 2.0)
    assert shifted[0] == f"\nverdict judged {round(4 * (ev - 2)) / 4:+g} EV from here"


def test_the_fits_sphere_alone_is_the_same_image_without_the_tables():
    t = table("lambert")
    r = fit(t, "lambert", **FAST)
    light = plots.SPHERE_LIGHTS[0][1]
    m, f, coverage, unmeasured = plots.sphere_images(t, r, light, size=32)
    alone = plots.sphere_images(t, r, light, size=32, with_measured=False)
    assert alone[0] is None and alone[3] is None
    np.testing.assert_array_equal(alone[1], f)
    np.testing.assert_array_equal(alone[2], coverage)
    assert np.isfinite(m).any() and unmeasured.shape == coverage.shape


@pytest.mark.slow
def test_exposure_brightens_table_and_fit_alike_before_the_tone_curve():
    t = table("lambert")
    r = fit(t, "lambert", **FAST)
    m, f, coverage, _ = plots.sphere_images(t, r, plots.SPHERE_LIGHTS[0][1], size=48)
    base, up = (plots._composite(m, coverage, np.zeros(3), ev) for ev in (0.0, 2.0))
    lit = base.sum(axis=-1) > 0.05
    assert np.all(up[lit] > base[lit])  # brighter everywhere lit ...
    assert up.max() < 1.0  # ... and compressed by the tone curve, not clipped
    measured = np.all(np.isfinite(m), axis=-1)  # the fit matches where there is a bin
    np.testing.assert_allclose(plots._composite(f, coverage, np.zeros(3), 2.0)[measured],
                               up[measured], atol=0.03)  # a few silhouette pixels
    png = plots.render("spheres", t, r, exposure_ev=1.5)
    assert_sane_png(png)
    assert png != plots.render("spheres", t, r)
    for bad in (12.5, -7, float("nan"), "bright"):
        with pytest.raises(ValueError, match="exposure_ev"):
            plots.render("spheres", t, r, exposure_ev=bad)
    with pytest.raises(ValueError, match="no sphere renders"):
        plots.render("slices", t, r, exposure_ev=1.0)


def test_spheres_are_antialiased():
    """Supersampled: the silhouette has pixels between background and sphere."""
    t = table("lambert")
    r = fit(t, "lambert", **FAST)
    _, _, coverage, _ = plots.sphere_images(t, r, plots.SPHERE_LIGHTS[0][1], size=64)
    partial = (coverage > 0.05) & (coverage < 0.95)
    assert partial.sum() > 64  # a ring of edge pixels
    _, _, hard, _ = plots.sphere_images(t, r, plots.SPHERE_LIGHTS[0][1], size=64, supersample=1)
    assert set(np.unique(hard)) <= {0.0, 1.0}


def test_a_colour_misfit_shows_in_the_colour_ratio():
    """A fit with too much blue tints the colour panel blue; the right fit is grey."""
    t = table("lambert")
    r = fit(t, "lambert", **FAST)
    bluer = FitResult.from_dict({**r.to_dict(),
                                 "params": {"kd": [r.params["kd"][0], r.params["kd"][1],
                                                   r.params["kd"][2] * 1.5]}})
    light = plots.SPHERE_LIGHTS[0][1]
    for result, blue in ((r, False), (bluer, True)):
        m, f, coverage, unmeasured = plots.sphere_images(t, result, light, size=48)
        _, colour = plots.ratio_images(m, f, (coverage > 0.5) & ~unmeasured)
        mean = np.nanmean(colour.reshape(-1, 3), axis=0)
        if blue:
            assert mean[2] > 0.7 and mean[0] < 0.5 and mean[1] < 0.5, mean
        else:
            np.testing.assert_allclose(mean, 0.5, atol=0.02)


def test_report_page_lists_parameters_with_errors_and_every_metric(ggx):
    _, result = ggx
    params, metrics = plots.summary_lines(result)
    assert any("±" in line for line in params)
    assert [m.split()[0] for m in metrics[:5]] == ["log_rmse", "cube_root_rmse", "rmse_cos",
                                                  "rel_peak_error", "sphere"]
    bound = plots.summary_lines(fit(table("lambert"), "ggx", **FAST))[0]
    assert "(bound)" in "".join(bound)
    # a long line (three bound RGB values) wraps under its first value, clear of the
    # errors column beside it
    assert all(len(line) <= plots.PARAM_LINE_CHARS for line in params + bound)
    assert any(line.startswith("  ? ") for line in bound)  # its reasons, wrapped too
    assert plots.wrap_values("kd     ", ["2.215e-09 (bound)"] * 3) == [
        "kd     2.215e-09 (bound),  2.215e-09 (bound),", "       2.215e-09 (bound)"]


def test_saved_plots_respect_the_umask(ggx, tmp_path):
    import os
    import stat

    t, r = ggx
    old = os.umask(0o022)
    try:
        (path,) = plots.save_all(t, r, tmp_path / "plots", kinds=("slices",))
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o644  # not mkstemp's 0600
    assert not [p for p in os.listdir(tmp_path / "plots") if p != "slices.png"]  # no leftovers


def test_polar_channel_labels_clear_every_tick_label(ggx):
    """Each channel's name sits above its half disc, overlapping no angle or radius
    label (it once covered the -30 degree one)."""
    t, r = ggx
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = plots.polar_figure(t, r)
    renderer = FigureCanvasAgg(fig).get_renderer()
    for ax in fig.axes:
        names = [x for x in ax.texts if x.get_text().endswith(" channel")]
        assert len(names) == 1
        box = names[0].get_window_extent(renderer)
        ticks = [lab for lab in ax.get_xticklabels() + ax.get_yticklabels()
                 if lab.get_text() and lab.get_visible()]
        assert ticks
        assert not [lab.get_text() for lab in ticks
                    if box.overlaps(lab.get_window_extent(renderer))]


def test_the_readme_layout_names_only_paths_that_exist():
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    text = (root / "README.md").read_text(encoding="utf-8")
    layout = text[text.index("## Layout"):]
    layout = layout[:layout.index("\n## ", 5)] if "\n## " in layout[5:] else layout
    named = {p for p in re.findall(r"`((?:brdffit|api|data_synth|bench|tests)/[\w/.]*)`", layout)}
    assert len(named) > 10
    assert sorted(p for p in named if not (root / p).exists()) == []


@pytest.mark.slow  # a fit and four sphere pictures: ~5 s
def test_a_dark_tables_spheres_are_also_drawn_where_the_verdict_judged_them(ggx, tmp_path):
    """black-fabric's verdict judged its spheres at +6 EV, where spheres.png (one exposure
    for every material) shows them near black: the pair is drawn again at that exposure."""
    from data_synth import make_table

    dark = make_table("lambert", {"kd": [0.006, 0.004, 0.003]})[0]
    r = fit(dark, "lambert", samples=2048)
    ev = plots.judged_ev(dark, plots.SPHERE_LIGHTS[0][1])
    assert ev >= plots.JUDGED_APART_EV
    paths = plots.save_all(dark, r, tmp_path / "dark", kinds=("spheres",))
    assert [p.rsplit("/", 1)[-1] for p in paths] == ["spheres.png", plots.JUDGED_SPHERES]
    plain, judged = (imread(p)[..., :3] for p in paths)
    assert judged.mean() > plain.mean() + 0.05  # the sphere is there to see
    t, r = ggx  # judged near the picture's own exposure: one file
    assert len(plots.save_all(t, r, tmp_path / "mid", kinds=("spheres",))) == 1


def test_the_colour_panel_tints_as_far_as_the_colours_look_apart():
    """A saturated red whose tiny blue channel is a quarter below the measured one (its
    share 0.4 stop off, tinted 0.2 by the share alone) looks CIEDE2000 ~1.5 off
    (red-plastic's ggx fit: the whole sphere was tinted orange); twice the green is far
    off and tinted."""
    from brdffit.fitting.colour import ciede2000, rgb_to_lab

    measured = np.broadcast_to([0.30, 0.06, 0.012], (4, 4, 3)).copy()
    on = np.ones((4, 4), bool)
    for fitted, tinted in (([0.30, 0.06, 0.009], False), ([0.30, 0.12, 0.012], True)):
        f = np.broadcast_to(fitted, (4, 4, 3)).copy()
        _, colour = plots.ratio_images(measured, f, on)
        swing = float(np.max(np.abs(colour - 0.5)))
        de = ciede2000(rgb_to_lab(np.array(fitted) / (np.array(fitted) @ plots.LUMINANCE)),
                       rgb_to_lab(measured[0, 0] / (measured[0, 0] @ plots.LUMINANCE)))
        assert (swing > 0.2 if tinted else swing < 0.1), (swing, de)
        assert (de > plots.TINT_FULL_DE) is tinted, de
    # one colour and an image's pixels give the same CIEDE2000
    lab = rgb_to_lab(np.array([[0.2, 0.1, 0.05], [0.05, 0.1, 0.2]]))
    from brdffit.fitting.colour import ciede2000_of
    np.testing.assert_allclose(ciede2000_of(lab[:1], lab[1:]), ciede2000(lab[0], lab[1]))


def test_the_colour_panel_judges_a_glossy_materials_diffuse_body():
    """The demo's ggx table: its diffuse body is 0.47% of its highlight, and the panel
    called it too dark to judge (black) where the verdict's picture shows it mid-grey."""
    measured = np.full((1, 3, 3), 0.05)
    measured[0, 0] = 10.6  # the highlight
    _, colour = plots.ratio_images(measured, measured.copy(), np.ones((1, 3), bool))
    np.testing.assert_allclose(colour[0, 1:], 0.5)  # judged, and the right hue
    measured[0, 2] = 1e-4  # far below: too dark to judge
    _, colour = plots.ratio_images(measured, measured.copy(), np.ones((1, 3), bool))
    assert np.isnan(colour[0, 2]).all()


@pytest.mark.parametrize("errors, tolerance", [((0.0, 3e-13, 7.5e-12), 0.005),
                                               ((0.0191, 0.0542, 0.03), 10.0)])
def test_the_ranking_draws_exact_fits_and_a_tolerance_far_beyond_them(errors, tolerance):
    """Every candidate exact to rounding (an axis 1e-11 wide, and the tolerance's label
    drawn at 0.005 beyond it: a picture too wide for matplotlib to make), or a
    tolerance far beyond every candidate (--tolerance 10: its label at x = 10 made the
    picture 25,875 px wide): a picture of the usual size, saying where the tolerance
    is."""
    from brdffit.view import plots

    rows = [{"model": m, "n_params": k, "log_rmse": e, "psnr_db": 30.0, "verdict": "good",
             "status": "chosen" if i == 0 else "within tolerance", "converged": True}
            for i, (m, k, e) in enumerate(zip(("lambert", "ggx", "ggx2"), (3, 8, 12), errors))]
    png = plots.ranking({"ranking": rows, "tolerance": tolerance, "chosen": "lambert",
                         "reason": "Chose lambert.", "table": "t.csv"})
    height, width = imread(io.BytesIO(png)).shape[:2]
    assert width < 1500 and height < 800, (width, height)


def test_a_sample_lists_plots_say_what_they_can_show(ggx, tmp_path):
    """A sample list's plots draw its binned table: 400 samples drew checkered spheres
    and empty slices beside a 'looks good' verdict, with nothing said. The slices,
    spheres and polar plots say how few bins the samples fill, and where to look."""
    from brdffit.fitting.samples import binned
    from brdffit.io.readers import read_measured
    from data_synth.__main__ import main as synth

    path = tmp_path / "lab.csv"
    assert synth(["samples", str(path), "--layout", "uniform", "-n", "400"]) == 0
    samples = read_measured(path)
    r = fit(samples, "ggx", **FAST)
    note = plots._few_samples(binned(samples)[0], r, "these slices")
    assert note.startswith("\na sample list: 400 samples in ")
    assert "few on these slices; the samples plot shows each of them" in note.replace("\n", " ")
    t, table_fit = ggx
    assert plots._few_samples(t, table_fit, "these slices") == ""


@pytest.mark.slow  # a fit and two report pages: ~8 s, the full suite's
def test_a_sample_lists_report_draws_its_samples_and_the_fits_spheres(tmp_path, monkeypatch):
    """report.png of a sample list's fit: its spheres were mostly checkered (the samples
    fill few bins); each sample fitted against measured, and the fit's own spheres, are
    drawn in their place, by the library, the CLI and the service's plot task alike.
    Without the samples (or for a table) the report is a table's."""
    from api.tasks import render_plot
    from brdffit.fitting.samples import binned
    from brdffit.io.readers import read_measured
    from brdffit.view import sample_plot
    from data_synth.__main__ import main as synth

    path = tmp_path / "lab.csv"
    assert synth(["samples", str(path), "--layout", "uniform", "-n", "400"]) == 0
    samples = read_measured(path)
    r = fit(samples, "lambert", **FAST)
    drawn = []
    draw = sample_plot.draw
    monkeypatch.setattr(sample_plot, "draw",
                        lambda fig, m, res: drawn.append(m.n) or draw(fig, m, res))
    table = binned(samples)[0]
    assert_sane_png(plots.render("report", table, r, measured=samples))
    assert drawn == [400]
    plots.render("slices", table, r, measured=samples)  # the other kinds draw the table
    assert drawn == [400]
    outcome = render_plot(str(path), "lab.csv", r.to_dict(), "report")
    assert outcome.value[:8] == b"\x89PNG\r\n\x1a\n" and drawn == [400, 400]
    # (the CLI's: test_a_sample_lists_samples_are_each_drawn)


def test_a_sample_lists_polar_plot_draws_its_samples_in_their_plane_of_incidence():
    """polar.png drew a sample list's binned table at 10, 30, 50 and 70 degrees, where
    a gonioreflectometer's in-plane samples (the commonest layout) seldom fall: "few on
    the plane of incidence". The samples in their plane are drawn at their own
    incident angles, forward (> 0) or back towards the light (< 0); a view out of the
    plane is not; an angle with too few samples is not drawn."""
    from brdffit.io.measurements import Measurements
    from brdffit.view.plots import IN_PLANE_MIN, in_plane_samples

    theta_o = np.array([-60.0, -30.0, 0.0, 20.0, 40.0, 70.0])
    n = theta_o.size
    # the light at 30 degrees from azimuth 90; forward is azimuth 270
    light = [30.0, 90.0]
    views_at = [(abs(t), 270.0 if t >= 0 else 90.0) for t in theta_o]
    rows = ([[*light, *v] for v in views_at]
            + [[30.0, 90.0, 40.0, 200.0]]  # out of the plane: not drawn
            + [[0.0, 0.0, 25.0, 123.0]] * 2  # an angle of two samples: too few
            + [[60.0, 10.0, 45.0, 190.0]] * IN_PLANE_MIN)  # forward of a light at 60
    a = np.radians(np.array(rows))
    rgb = np.linspace(0.1, 1.0, len(rows))[:, None] * np.ones(3)
    m = Measurements.from_angles(a[:, 0], a[:, 1], a[:, 2], a[:, 3], rgb)
    # a light a hair off the normal is on it: every view is in a plane with it, forward
    near = np.radians(np.array([[0.05, 90.0, 30.0, az] for az in (0.0, 70.0, 200.0)]))
    overhead = in_plane_samples(Measurements.from_angles(*near.T, np.full((3, 3), 0.2)))
    assert list(overhead) == [0.0]
    np.testing.assert_allclose(np.degrees(overhead[0.0][0]), 30.0, atol=1e-9)
    found = in_plane_samples(m)
    assert sorted(found) == [30.0, 60.0]
    at, values = found[30.0]
    np.testing.assert_allclose(np.degrees(at), theta_o, atol=1e-9)
    np.testing.assert_allclose(values, rgb[:n])
    np.testing.assert_allclose(np.degrees(found[60.0][0]), 45.0, atol=1e-9)
    r = FitResult("lambert", {"kd": [0.3, 0.3, 0.3]}, {"log_rmse": 0.1}, True, "successful",
                  1, 0.1, {}, input={"fitted_at": "samples", "samples": len(rows)})
    from brdffit.fitting.samples import binned

    fig = plots.polar_figure(binned(m)[0], r, measured=m)
    assert "lie in their plane of incidence at these 2 incident angles" in fig._suptitle.get_text()
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert legend[:2] == ["θi = 30°", "θi = 60°"]


@pytest.mark.slow  # two CLI fits with their plots: the full suite's
def test_a_sample_lists_samples_are_each_drawn(tmp_path, monkeypatch):
    """samples.png: each sample's fitted value at its own directions against the
    measured one, and where the fit is off, for a sample list (its other plots draw the
    few bins it fills); a table gets none. Many samples are drawn as a subset, said so;
    a value of 0 cannot sit on log axes, and the title says how many."""
    from brdffit.io.readers import read_measured
    from brdffit.view import sample_plot
    from data_synth.__main__ import main as synth

    path = tmp_path / "lab.csv"
    assert synth(["samples", str(path), "--layout", "uniform", "-n", "400", "--noise",
                  "0.05"]) == 0
    out = tmp_path / "plots"
    drawn = []
    draw = sample_plot.draw
    monkeypatch.setattr(sample_plot, "draw",
                        lambda fig, m, res: drawn.append(m.n) or draw(fig, m, res))
    assert cli_main(["fit", str(path), "--model", "lambert", "--plots", str(out)]) == 0
    assert drawn == [400, 400]  # samples.png, and report.png in place of its spheres
    png = (out / "samples.png").read_bytes()
    height, width = imread(io.BytesIO(png)).shape[:2]
    assert width > 1000 and height > 500
    samples = read_measured(path)
    r = fit(samples, "lambert", **FAST)
    title = sample_plot._title(samples, r, samples.n, 0)
    assert "400 samples; held-out log_rmse" in title and "in-sample" in title
    assert "of 400 samples (a random subset)" in sample_plot._title(samples, r, 100, 3)
    assert "3 with a value <= 0" in sample_plot._title(samples, r, 100, 3)
    zeroed = dataclasses.replace(samples, rgb=np.where(np.arange(samples.n)[:, None] < 7,
                                                       0.0, samples.rgb))
    assert sample_plot.samples(zeroed, r)[:8] == b"\x89PNG\r\n\x1a\n"
    # (a table's plots have no samples.png: test_cli_fit_writes_plots)


def test_the_ranking_draws_the_psnr_its_rule_ranked_by():
    """Under the render rule the ranking draws each candidate's PSNR under the render
    loss's eight lights (what the rule and its reason use), else the sphere's; a
    render that was not measured is drawn as none, and the plot still draws."""
    from brdffit.view.plots import ranked_psnr, ranking

    row = {"psnr_db": 35.7, "views_psnr_db": 34.5}
    assert ranked_psnr(row, "render_psnr_db") == 34.5
    assert ranked_psnr(row, "log_rmse") == 35.7
    assert ranked_psnr({"psnr_db": 30.0, "views_psnr_db": None}, "render_psnr_db") == 30.0
    assert ranked_psnr({"psnr_db": float("nan")}, "log_rmse") is None
    rows = [{"model": m, "n_params": n, "status": st, "log_rmse": e, "psnr_db": p,
             "views_psnr_db": v, "verdict": "good"}
            for m, n, st, e, p, v in (("ggx", 8, "chosen", 0.01, 35.7, 34.5),
                                      ("ggx2", 12, "looks worse", 0.009, None, None))]
    png = ranking({"ranking": rows, "rule": "render_psnr_db", "tolerance": 0.005,
                   "chosen": "ggx", "reason": "Chose ggx by its sphere renders.",
                   "table": "t.binary"})
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_colour_maps_label_names_the_figure_it_is_and_the_verdicts_beside_it():
    """The map shows the displayed picture's hue; its label gave that mean as "the
    verdict's" where the verdict judged the radiance figure (1.5 beside a reason of 3.3:
    color-changing-paint1's generalized_schlick)."""
    from brdffit import FitResult
    from brdffit.view.plots import _colour_label

    def look(displayed, radiance):
        q = {"displayed_colour_shift": displayed, "colour_shift": radiance}
        return FitResult("ggx", {}, {}, True, "successful", 1, 0.1, {}, quality=q)

    assert _colour_label(look(1.5, 3.3), 0) == ("mean as displayed: CIEDE2000 1.5\n"
                                                "the verdict's: 3.3 in radiance")
    assert _colour_label(look(1.5, 0.8), 0) == "mean as displayed: CIEDE2000 1.5"
    assert _colour_label(look(None, 0.8), 0) is None and _colour_label(look(1.5, 3.3), 2) is None


def test_a_sample_lists_slices_are_where_its_samples_are():
    """An in-plane list's binned samples are all at phi_d 0 or 180: its report's slices
    at 90 promised dots that never appeared. They are drawn at the fullest phi_d."""
    from brdffit.fitting.samples import binned
    from brdffit.view.plots import _fullest_phi_d
    from data_synth.sparse import sample_model

    in_plane, _ = sample_model("ggx", None, "in_plane", 600, seed=3)
    table = binned(in_plane)[0]
    fullest = _fullest_phi_d(table)
    assert min(fullest, 180.0 - fullest) < 1.0
    i_pd = int(fullest)  # bins of 1 degree: the centre 0.5 is bin 0, 179.5 bin 179
    assert table.mask[:, :, i_pd].sum() == table.mask.sum(axis=(0, 1)).max() > 0
