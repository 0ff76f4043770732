"""How good is a fit? Four pictures of a table and its fit, each as PNG bytes.

- :func:`slices`: measured vs fitted f_r against theta_h, a panel per theta_d,
  at phi_d = 90 deg (the view of Ngan et al. 2005), log f_r;
- :func:`error_map`: the fit's per-bin error over (theta_h, theta_d), the very
  residual that ``log_rmse`` aggregates (``brdffit.fitting.loss``), and its sign;
- :func:`spheres`: table and fit rendered on a sphere under two lights, with the
  ratio of the two images;
- :func:`polar`: f_r in the plane of incidence for a few incident angles, per channel;
- :func:`report`: one page per fit: parameters with errors, metrics, the above.

The measured table is read by its reference nearest-bin lookup
(:meth:`MerlTable.lookup`), the fit is evaluated by its model in JAX; unmeasured
bins show as grey, never as zero. Figures are built on ``matplotlib.figure.Figure``
with the Agg canvas, not ``pyplot``: no global state, no display, safe in threads
and worker processes.

theta_h axes use a square-root scale: that is the MERL table's own spacing, so
the few degrees around the specular peak get as much room as the rest.
"""

from __future__ import annotations

import io
import os
import textwrap
import warnings
from collections.abc import Callable

import numpy as np

from brdffit import extras

try:
    from matplotlib.colors import LogNorm, to_rgb
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle, Patch
except ModuleNotFoundError:
    raise extras.MissingExtraError("brdffit.view.plots", "plots", ("matplotlib",)) from None

from brdffit.fitting.colour import DISPLAY_Y, ciede2000_of, rgb_to_lab
from brdffit.fitting.problem import sphere_reference
from brdffit.fitting.quality import ALIKE_DB, GOOD, POOR, judged_brightness, judged_colour
from brdffit.fitting.result import FitResult, error_measures_nothing
from brdffit.fitting.sphere import (
    LIGHTS,
    displayed_level,
    radiance,
    sphere_disc,
    table_exposure,
    tonemap,
)
from brdffit.io import atomic
from brdffit.io.angles import (
    N_PHI_D,
    N_THETA_D,
    N_THETA_H,
    bin_centres,
    half_diff_to_bins,
    half_diff_to_dirs,
)
from brdffit.io.grid import bin_grid
from brdffit.io.measurements import Measurements
from brdffit.io.merl import MerlTable
from brdffit.view.drawing import (
    CHANNELS,
    DPI,
    LUMINANCE,
    NO_DATA,
    as_result,
    evaluate,
    png_bytes,
    source_name,
    sqrt_degree_axis,
)
from brdffit.view.kinds import EXPOSURE_EV_RANGE, KINDS, check_exposure_ev, exposure_refused


def _title(table: MerlTable, result: FitResult) -> str:
    name = source_name(table.source)
    e = result.error.get("log_rmse")
    # the loss it minimised, where not the default: a render-loss fit's pictures were
    # told from a log-loss one's by the log_rmse figure alone
    loss = f" ({result.loss} loss)"
    # how it looks, beside the number: a first look at spheres.png gave log_rmse alone
    # (a review: "no sphere figure states PSNR or verdict")
    psnr = result.error.get("psnr_db")
    verdict = (result.quality or {}).get("verdict")
    judged = "held-out PSNR" if _on_samples(result) else "sphere PSNR"
    look = ("" if psnr is None else f", {judged} {psnr:.1f} dB") + (
        f", looks {verdict}" if verdict else "")
    return (f"{name}: {result.model} fit{loss}, log_rmse "
            + ("n/a" if e is None else f"{e:.3g}") + look)


def _few_samples(table: MerlTable, result: FitResult, what: str) -> str:
    """For a fit of a sample list, what the plots of its binned table can show: its
    samples fill a few of the grid's bins, and few of those lie on ``what`` (a list of
    400 samples drew checkered spheres and empty slices beside a "looks good" verdict,
    with nothing said); "" for a table."""
    if (result.input or {}).get("fitted_at") != "samples":
        return ""
    n = (result.input or {}).get("samples")
    note = (f"a sample list: {n if n is not None else 'its'} samples in {table.n_measured:,} "
            f"of the grid's bins, few on {what}; the samples plot shows each of them, and the "
            "verdict judges the held-out samples")
    return "\n" + "\n".join(textwrap.wrap(note, 100))


def _theta_h_edges_deg() -> np.ndarray:
    return (np.arange(N_THETA_H + 1) / N_THETA_H) ** 2 * 90.0


# -- slices -------------------------------------------------------------------------


#: phi_d of the slice rows. Isotropy and reciprocity make phi_d and 180 - phi_d the
#: same bin, so 0 .. 90 covers the table: 90 is the view of Ngan et al. 2005, 0 the
#: plane that holds both directions (retro- and forward scattering).
SLICE_PHI_D = (90.0, 45.0, 0.0)


def slices(
    table: MerlTable, result: FitResult | dict, *, theta_d_deg=(1.0, 30.0, 60.0, 80.0),
    phi_d_deg=SLICE_PHI_D,
) -> bytes:
    """Measured (dots) and fitted (lines) f_r against theta_h, one panel per theta_d,
    one row per phi_d."""
    result = as_result(result)
    phi_d_deg = tuple(np.atleast_1d(phi_d_deg).tolist())
    fig = Figure(figsize=(13.0, 2.0 + 2.9 * len(phi_d_deg)), layout="constrained")
    _draw_slices(fig, table, result, theta_d_deg, phi_d_deg)
    # the bins' centres, as the rows give them (asked 90, shown 90.5)
    shown = ", ".join(f"{p:.1f}°" for p in _phi_d_centres(phi_d_deg))
    fig.suptitle(f"{_title(table, result)}  |  slices at φd = {shown}"
                 f"{_few_samples(table, result, 'these slices')}", fontsize=12)
    return png_bytes(fig)


def _fullest_phi_d(table: MerlTable) -> float:
    """The centre (degrees) of the phi_d bin holding most measured bins: a sample list's
    slices, where its samples lie (an in-plane list's are all at phi_d 0 or 180, and its
    report's slices at 90 promised dots that never appeared)."""
    counts = table.mask.sum(axis=(0, 1))
    return float(np.degrees(bin_centres(0, 0, int(np.argmax(counts)))[2]))


def _phi_d_centres(phi_d_deg) -> list[float]:
    """The centre (degrees) of the phi_d bin each of ``phi_d_deg`` falls in."""
    out = []
    for phi in phi_d_deg:
        _, _, i_pd = half_diff_to_bins(0.0, 0.0, np.radians(phi))
        out.append(float(np.degrees(bin_centres(0, 0, int(np.ravel(i_pd)[0]))[2])))
    return out


def _draw_slices(fig, table, result, theta_d_deg, phi_d_deg):
    axes = np.atleast_2d(fig.subplots(len(phi_d_deg), len(theta_d_deg), sharey=True,
                                      sharex=True, squeeze=False))
    i_th = np.arange(N_THETA_H)
    lo, hi = np.inf, 0.0
    zeros = []  # (axis, theta_h, colour) of bins measured 0: no point on a log axis
    for row, phi in enumerate(phi_d_deg):
        _, i_tds, i_pd = half_diff_to_bins(
            np.zeros(len(theta_d_deg)), np.radians(theta_d_deg), np.radians(phi))
        i_pd = int(np.ravel(i_pd)[0])
        i_tds = np.atleast_1d(i_tds)
        theta_h, theta_d, phi_d = bin_centres(i_th[None, :], i_tds[:, None], i_pd)
        theta_h, theta_d, phi_d = np.broadcast_arrays(theta_h, theta_d, phi_d)
        fitted_all = evaluate(result, *half_diff_to_dirs(theta_h, theta_d, phi_d))
        for p, (ax, i_td) in enumerate(zip(axes[row], i_tds, strict=True)):
            fitted = fitted_all[p]
            measured = np.where(table.mask[i_th, i_td, i_pd], table.rgb[:, i_th, i_td, i_pd],
                                np.nan).T
            x = np.degrees(theta_h[p])
            for c, (_, colour) in enumerate(CHANNELS):
                ax.plot(x, measured[:, c], "o", ms=3.0, color=colour, alpha=0.55, mec="none")
                ax.plot(x, fitted[:, c], "-", lw=1.5, color=colour)
                zero = measured[:, c] <= 0
                if zero.any():
                    zeros.append((ax, x[zero], colour))
            for v in (measured, fitted):
                v = v[np.isfinite(v) & (v > 0)]
                if v.size:
                    lo, hi = min(lo, v.min()), max(hi, v.max())
            ax.set_yscale("log")
            sqrt_degree_axis(ax)
            ax.grid(True, which="major", alpha=0.3)
            ax.set_title(f"θd = {np.degrees(theta_d[p, 0]):.1f}°", fontsize=10)
            if row == len(phi_d_deg) - 1:
                ax.set_xlabel("θh (degrees, √ scale)")
        # the bin centre actually shown, as the panel titles give theta_d's
        axes[row, 0].set_ylabel(f"φd = {np.degrees(phi_d[0, 0]):.1f}°\nf_r (1/sr, log)")
    if hi > 0:
        axes[0, 0].set_ylim(lo / 2, hi * 2)
    # a measured 0 (chrome-steel: 14% of its bins) drawn on the axis's floor: left out,
    # the dots stopped where the fit's line went on, as if nothing were measured there
    floor = axes[0, 0].get_ylim()[0] * 1.4
    for ax, x, colour in zeros:
        ax.plot(x, np.full(x.shape, floor), "v", ms=3.5, mfc="none", mec=colour, alpha=0.7,
                mew=0.8)
    fig.legend(
        handles=[Line2D([], [], ls="none", marker="o", color="0.3", label="measured"),
                 *([Line2D([], [], ls="none", marker="v", mfc="none", mec="0.3",
                          label="measured 0")] if zeros else []),
                 Line2D([], [], color="0.3", label="fit")]
        + [Line2D([], [], color=col, lw=4, label=name) for name, col in CHANNELS],
        loc="outside right upper", fontsize=9,
    )
    return axes


# -- error map ----------------------------------------------------------------------


def bin_residuals(table: MerlTable, result: FitResult | dict) -> np.ndarray:
    """Per-bin residual of the loss, log(1 + f_fit cos_i) - log(1 + f_meas cos_i),
    shape (3, 90, 90, 180); NaN where the bin is unmeasured or below the horizon."""
    g = bin_grid()
    above = np.flatnonzero(g.above_horizon)
    fitted = evaluate(result, g.wi[above], g.wo[above])  # fixed shape: compiled once
    keep = table.mask.ravel()[above]
    idx, fitted = above[keep], fitted[keep]
    measured = table.rgb.reshape(3, -1)[:, idx].T
    cos_i = g.cos_i[idx, None]
    r = np.full((3, g.cos_i.size), np.nan)
    r[:, idx] = (np.log1p(np.maximum(fitted, 0) * cos_i) - np.log1p(measured * cos_i)).T
    return r.reshape(3, N_THETA_H, N_THETA_D, N_PHI_D)


def error_map(table: MerlTable, result: FitResult | dict) -> bytes:
    """RMS and mean of the per-bin residual over phi_d and RGB, on (theta_h, theta_d)."""
    result = as_result(result)
    fig = Figure(figsize=(12.0, 4.8), layout="constrained")
    _draw_error_map(fig, table, result)
    # two lines: on one, a long table name ran off both edges of the figure
    fig.suptitle(f"{_title(table, result)}\naveraged over φd and RGB; grey: no measured bin",
                 fontsize=12)
    return png_bytes(fig)


def _draw_error_map(fig, table: MerlTable, result: FitResult):
    r = bin_residuals(table, result)
    n = np.count_nonzero(np.isfinite(r), axis=(0, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.nansum(r * r, axis=(0, 3)) / n)
        bias = np.nansum(r, axis=(0, 3)) / n
    x = _theta_h_edges_deg()
    y = np.linspace(0.0, 90.0, N_THETA_D + 1)
    ax_rms, ax_bias = fig.subplots(1, 2, sharey=True)
    finite_rms = rms[np.isfinite(rms) & (rms > 0)]
    # log-scaled: the residuals span decades, and the grazing strip (theta_d > 80 deg)
    # set a linear scale that left ~90% of the bins black (white-diffuse-bball: a bar
    # to 1.0, every bin below 75 deg under 0.073)
    vmax = max(float(finite_rms.max()) if finite_rms.size else 1.0, 1e-9)
    vmin = max(float(np.percentile(finite_rms, 1.0)) if finite_rms.size else 0.0,
               vmax / ERROR_MAP_DECADES_RANGE)
    shown = np.where(np.isfinite(rms), np.maximum(rms, vmin), np.nan)  # NaN: no bin, grey
    m = ax_rms.pcolormesh(x, y, shown.T, cmap=_with_bad("magma"),
                          norm=LogNorm(vmin=min(vmin, vmax / 10), vmax=vmax), shading="flat",
                          rasterized=True)
    fig.colorbar(m, ax=ax_rms, label="RMS residual of log(1 + f_r cos θi)", extend="min")
    ax_rms.set_title("|error| per bin (log_rmse's terms, before its solid-angle weights)",
                     fontsize=11)

    finite_bias = np.abs(bias[np.isfinite(bias)])
    # the 95th percentile: a few grazing or peak bins (theta_d > 85, theta_h < 1 deg) set
    # the 99.5th, and left the rest of the map white where the |error| map shows 1e-2;
    # beyond it, the bar's arrows
    bmax = float(np.percentile(finite_bias, 95.0)) if finite_bias.size else 1.0
    m = ax_bias.pcolormesh(x, y, bias.T, cmap=_with_bad("RdBu_r"), vmin=-max(bmax, 1e-6),
                           vmax=max(bmax, 1e-6), shading="flat", rasterized=True)
    fig.colorbar(m, ax=ax_bias, label="mean residual: fit − measured", extend="both")
    ax_bias.set_title("sign: red = fit too bright, blue = too dark", fontsize=11)

    for ax in (ax_rms, ax_bias):
        sqrt_degree_axis(ax)
        ax.set_facecolor(NO_DATA)
        ax.set_xlabel("θh (degrees, √ scale)")
    for ax in (ax_rms, ax_bias):  # each its own: the left bar's label read as the right's
        ax.set_ylabel("θd (degrees)")
        ax.set_yticks([0, 15, 30, 45, 60, 75, 90])
        ax.tick_params(labelleft=True)


#: The |error| map's colour scale spans at most this factor below its largest bin.
ERROR_MAP_DECADES_RANGE = 1e4


def _with_bad(name: str):
    from matplotlib import colormaps

    return colormaps[name].with_extremes(bad=NO_DATA)


# -- spheres ------------------------------------------------------------------------

SPHERE_BACKGROUND = "#33404f"
#: The plots' lights: brdffit.fitting.sphere's two (what the PSNR measures), and a back
#: light 135 deg from the camera. Its lit crescent has light and camera at opposite
#: grazing angles (theta_d ~ 68 deg), where the Fresnel rise shows.
SPHERE_LIGHTS = (
    ("key light\n45° above-left", LIGHTS[0][1]),
    ("grazing light\n80° from the right", LIGHTS[1][1]),
    ("back light 135° from\nthe camera: Fresnel rim", np.array([0.7071, 0.0, -0.7071])),
)
#: The colour panel: 0.5 + COLOUR_GAIN * log2(channel share, fit / measured), so
#: one stop of a channel's share saturates that channel, scaled by how far apart the
#: two colours look (their CIEDE2000 at equal luminance over TINT_FULL_DE): a
#: channel that holds little of the light (red-plastic's blue) swings its share by a
#: stop where the colour is all but the same, and the whole sphere was tinted orange
#: on a fit whose colour is CIEDE2000 1.1 off.
COLOUR_GAIN = 0.5
#: The colour panel judges the pixels whose measured picture, at the exposure the
#: verdict judged that light at, shows above this displayed level (Reinhard luminance
#: before the sRGB curve: ~10% on screen, a dark grey whose hue can still be told).
#: A share of the brightest pixel (it was 0.05%) left black, "too dark to judge", the
#: body a dark glossy material's picture shows: black-obsidian's red body under its
#: grey highlight (~1e-4 of it), which the verdict's picture shows mid-red against the
#: fit's grey.
DARKEST_SHOWN = 0.01
#: The CIEDE2000 (at equal luminance) at which the tint is full: the poor
#: verdict's colour (CIEDE2000 6, ``brdffit.fitting.quality.POOR``).
TINT_FULL_DE = 6.0
#: One exposure for every table, fit and light: a white Lambertian surface facing the
#: light has radiance 1 and shows at Reinhard 0.5 (sRGB 0.74). A dark material looks
#: dark and a bright one bright, as a renderer would show them under the same light.
EXPOSURE = 1.0
#: Samples per pixel side: a smooth silhouette and terminator.
SUPERSAMPLE = 3


def _block_mean(a: np.ndarray, k: int) -> np.ndarray:
    """Mean over k x k pixel blocks of an (n k, n k, ...) image, NaN-aware."""
    n = a.shape[0] // k
    b = a.reshape(n, k, n, k, *a.shape[2:])
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN block is NaN: off the disc
        return np.nanmean(b, axis=(1, 3))


def sphere_images(table: MerlTable, result: FitResult | dict, light: np.ndarray,
                  size: int = 200, supersample: int = SUPERSAMPLE, *,
                  with_measured: bool = True):
    """Anti-aliased radiance images of the table and the fit under ``light``.

    Returns ``(measured, fitted, coverage, unmeasured)``: (size, size, 3) radiance
    (black where unlit; the measured image NaN where the table has no bin), the
    fraction of each pixel on the sphere's disc, and the pixels whose samples are
    mostly unmeasured. ``with_measured=False``: the fit's image alone (measured and
    unmeasured None), where the table's would not be drawn (a sample list's report:
    its table is mostly unmeasured bins; their lookup was ~100 ms of it).
    """
    result = as_result(result)
    n = size * supersample
    wi, wo, inside = sphere_disc(n, light)
    lit = inside & (wi[..., 2] > 0) & (wo[..., 2] > 0)
    fitted = np.zeros((n, n, 3))
    fitted[lit] = evaluate(result, wi, wo)[lit]  # every pixel: one compiled shape
    fitted = radiance(fitted, wi)
    fitted[~inside] = np.nan  # off the disc: not part of the pixel's average
    fitted_image = _block_mean(fitted, supersample)
    coverage = _block_mean(inside.astype(float), supersample)
    if not with_measured:
        return None, fitted_image, coverage, None
    measured = np.zeros((n, n, 3))
    measured[lit] = table.lookup(wi[lit], wo[lit])
    measured = radiance(measured, wi)
    missing = inside & ~np.all(np.isfinite(measured), axis=-1)
    measured[~inside] = np.nan
    unmeasured = _block_mean(missing.astype(float), supersample) > 0.5 * np.maximum(coverage, 1e-9)
    return _block_mean(measured, supersample), fitted_image, coverage, unmeasured


def ratio_images(measured: np.ndarray, fitted: np.ndarray, on: np.ndarray,
                 exposure: float | None = None):
    """The brightness ratio, log2(fit / measured) of the luminance, and the colour
    ratio image of two radiance images: per channel ``0.5 + strength * COLOUR_GAIN *
    log2(share_fit / share_measured)`` with ``share`` a channel's part of the
    luminance and ``strength`` the two colours' CIEDE2000 at equal luminance
    over :data:`TINT_FULL_DE` (at most 1), so grey where the colour looks right and
    tinted towards the colour the fit has too much of. NaN off ``on`` and where both
    are black; the colour also where the measured picture, at ``exposure`` (the
    verdict's; by default the table's own, as the verdict takes it), shows darker
    than :data:`DARKEST_SHOWN`. A measured 0 under a lit fit is the fit too bright
    (chrome-steel: 14% of its bins are 0, and the fit's grey body there was black,
    "unlit", in the panel)."""
    lum_m, lum_f = measured @ LUMINANCE, fitted @ LUMINANCE
    lit = on & ((lum_m > 0) | (lum_f > 0))
    eps = 1e-3 * max(float(np.median(lum_m[lit])) if lit.any() else 1.0, 1e-9)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(lit, np.log2((lum_f + eps) / (lum_m + eps)), np.nan)
        share = ((fitted + eps) / (lum_f[..., None] + eps)) / (
            (measured + eps) / (lum_m[..., None] + eps))
        shown = [DISPLAY_Y * (img + eps) / (lum[..., None] + eps)
                 for img, lum in ((fitted, lum_f), (measured, lum_m))]
        apart = ciede2000_of(rgb_to_lab(shown[0]), rgb_to_lab(shown[1]))
        strength = np.clip(apart / TINT_FULL_DE, 0.0, 1.0)[..., None]
        colour = np.clip(0.5 + strength * COLOUR_GAIN * np.log2(share), 0.0, 1.0)
    if exposure is None:
        exposure = table_exposure(lum_m[lit]) if lit.any() else 1.0
    bright = lit & (displayed_level(np.nan_to_num(measured), exposure) > DARKEST_SHOWN)
    colour[~bright] = np.nan
    return ratio, colour


def _composite(rad: np.ndarray, coverage: np.ndarray, background: np.ndarray,
               exposure_ev: float = 0.0) -> np.ndarray:
    # before the tone curve, as a camera's exposure: the highlight compresses, the
    # diffuse brightens, table and fit by the same factor
    img = tonemap(np.nan_to_num(rad), EXPOSURE * 2.0**exposure_ev)
    return coverage[..., None] * img + (1.0 - coverage[..., None]) * background


def _exposure_words(exposure_ev: float) -> str:
    return "" if exposure_ev == 0 else f", exposure {exposure_ev:+g} EV"


def spheres(table: MerlTable, result: FitResult | dict, *, size: int = 200,
            exposure_ev: float = 0.0) -> bytes:
    """Table and fit on a sphere under three lights, their brightness ratio and their
    colour ratio; ``exposure_ev`` brightens (or darkens) both renders by that many
    stops before tone mapping (the ratio panels do not change)."""
    result = as_result(result)
    exposure_ev = check_exposure_ev(exposure_ev)
    fig = Figure(figsize=(13.5, 10.0), layout="constrained")
    _, checkered = _draw_spheres(fig, table, result, size, exposure_ev=exposure_ev)
    # its second line in fewer words: with " at 0 EV" it ran past both edges of the figure
    fig.suptitle(f"{_title(table, result)}{_exposure_words(exposure_ev)}\none exposure for "
                 "table and fit (white diffuse facing the light: mid-grey"
                 f"{' at 0 EV' if exposure_ev else ''}); camera on the normal"
                 f"{_CHECKERED if checkered else ''}"
                 f"{_few_samples(table, result, 'the spheres')}", fontsize=12)
    return png_bytes(fig)


def judged_ev(table: MerlTable, light, exposure_ev: float = 0.0) -> float | None:
    """At how many stops over a picture exposed at ``exposure_ev`` the verdict judged
    ``light`` (to a quarter stop; None for a light it did not judge). The verdict
    exposes each light at the table's own typical lit pixel
    (``brdffit.fitting.sphere.table_exposure``), the picture at one exposure for every
    material: what looks alike here may differ there (a highlight blown out in both at
    the verdict's exposure), and a dark material is near black here."""
    exposure = verdict_exposure(table, light)
    if exposure is None:
        return None
    return round(4 * np.log2(exposure / (EXPOSURE * 2.0**exposure_ev))) / 4


def verdict_exposure(table: MerlTable, light) -> float | None:
    """The exposure the verdict judged ``light`` at (None for a light it did not judge):
    the table's own typical lit pixel (``brdffit.fitting.sphere.table_exposure``)."""
    reference = sphere_reference(table)  # the fit's own, where it fitted this table object
    return next((e for judged, e in zip(reference.lights, reference.exposures, strict=True)
                 if np.allclose(judged, light, rtol=0.0, atol=1e-12)), None)


def _verdict_exposure_words(table: MerlTable, lights, exposure_ev: float) -> dict[int, str]:
    """Per row of a verdict's light: at how many stops over this picture's exposure the
    verdict judged it (:func:`judged_ev`), so the figure says which one was judged."""
    words = {}
    for row, (_, light) in enumerate(lights):
        ev = judged_ev(table, light, exposure_ev)
        if ev is not None:
            # from this picture's exposure: at the slider's +7 it reads +0 (the page's
            # hint and a reader took "at +7 EV" for the verdict's own exposure)
            words[row] = f"\nverdict judged {ev:+g} EV from here"
    return words


def _checker(size: int, cell: int = 4) -> np.ndarray:
    """A (size, size, 3) checkerboard of two light greys: where a sphere's bin is not
    measured. One flat grey read as "right hue" in the colour panel, whose grey is
    that, and as a match (0 stops) in the brightness panel."""
    i, j = np.indices((size, size)) // cell
    light = np.array(to_rgb(NO_DATA))
    return np.where(((i + j) % 2 == 0)[..., None], light, light * 0.8)


def _colour_label(result: FitResult, row: int) -> str | None:
    """The colour map's label for the sphere row ``row`` (0: the key light, 1: the
    grazing one; None for the others, and where the fit has no verdict): the CIEDE2000
    of the mean displayed colours, what the map's pixels show, and the verdict's own
    figure beside it where that is the radiance one (color-changing-paint1's map read
    1.5 where the verdict said 3.3, and the two looked at odds)."""
    q = result.quality or {}
    figures = q if row == 0 else q.get("grazing") if row == 1 else None
    value = (figures or {}).get("displayed_colour_shift")
    if not (isinstance(value, int | float) and np.isfinite(value)):
        return None
    label = f"mean as displayed: CIEDE2000 {value:.1f}"
    judged, where = judged_colour(figures)
    if where == "in radiance" and isinstance(judged, int | float) and judged > value:
        label += f"\nthe verdict's: {judged:.1f} in radiance"
    return label


#: What the spheres' caption says of their checkered pixels, where any are drawn (every
#: caption said it, over tables that have none).
_CHECKERED = "; checkered: unmeasured bin"


def _draw_spheres(fig, table: MerlTable, result: FitResult, size: int, lights=SPHERE_LIGHTS,
                  exposure_ev: float = 0.0, label_size: float = 10):
    """The sphere panels; returns their axes and whether any pixel is checkered (its
    bin unmeasured)."""
    axes = np.atleast_2d(fig.subplots(len(lights), 4))
    checkered = False
    background = np.array(to_rgb(SPHERE_BACKGROUND))
    no_data = _checker(size)
    ratio_img = colour_img = None
    verdict_ev = _verdict_exposure_words(table, lights, exposure_ev)
    for row, (label, light) in enumerate(lights):
        measured, fitted, coverage, unmeasured = sphere_images(table, result, light, size)
        images = [_composite(measured, coverage, background, exposure_ev),
                  _composite(fitted, coverage, background, exposure_ev)]
        images[0][unmeasured] = no_data[unmeasured]
        checkered = checkered or bool(unmeasured.any())
        on = (coverage > 0.5) & ~unmeasured
        ratio, colour = ratio_images(measured, fitted, on, verdict_exposure(table, light))
        for col, img in enumerate(images):
            axes[row, col].imshow(img, interpolation="bilinear")
        base = np.where(on[..., None], 0.0, background)
        base[unmeasured] = no_data[unmeasured]
        axes[row, 2].imshow(base, interpolation="nearest")
        ratio_img = axes[row, 2].imshow(np.ma.masked_invalid(ratio), cmap="RdBu_r",
                                        vmin=-2, vmax=2, interpolation="nearest")
        axes[row, 3].imshow(base, interpolation="nearest")
        colour_img = np.where(np.isnan(colour), base, colour)
        axes[row, 3].imshow(colour_img, interpolation="nearest")
        axes[row, 0].set_ylabel(label + verdict_ev.get(row, ""), fontsize=label_size)
        label_de = _colour_label(result, row)
        if label_de is not None:
            # each pixel's tint saturates at TINT_FULL_DE, the verdict judges the mean
            # colour: a teal sphere read 0.8, and the two looked at odds (a review)
            axes[row, 3].text(0.5, 0.02, label_de,
                              transform=axes[row, 3].transAxes, ha="center",
                              va="bottom", fontsize=label_size - 2, color="white",
                              bbox={"facecolor": "black", "alpha": 0.55, "pad": 1.5,
                                    "edgecolor": "none"})
        for ax in axes[row]:  # the unlit part is black: outline the sphere
            ax.add_patch(Circle(((size - 1) / 2, (size - 1) / 2), size / 2, fill=False,
                                lw=0.8, ec="0.65"))
    for col, name in enumerate(("measured (nearest bin)", f"fit ({result.model})",
                                "brightness: log₂(fit / measured)",
                                "colour: fit's hue over measured")):
        axes[0, col].set_title(name, fontsize=11)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(ratio_img, ax=axes[:, 2], shrink=0.6, extend="both", location="bottom",
                 label="stops (+1: fit 2× brighter)")
    axes[-1, 3].set_xlabel("grey: right hue; tinted: the fit has too much\nof that colour "
                           f"(full at CIEDE2000 {TINT_FULL_DE:g}); black: unlit, or\ntoo dark "
                           "to judge at the verdict's exposure", fontsize=9)
    return axes, checkered


# -- polar --------------------------------------------------------------------------


POLAR_THETA_I = (10.0, 30.0, 50.0, 70.0)


def polar(
    table: MerlTable, result: FitResult | dict, *, theta_i_deg=POLAR_THETA_I,
    measured: Measurements | None = None,
) -> bytes:
    """f_r in the plane of incidence, log radius, per incident angle: one half disc
    per channel (R, G, B) on one radial scale, so a colour misfit shows as curves
    that fit in one channel and miss in another. ``measured``: the sample list
    ``result`` was fitted to, whose samples in the plane of incidence are drawn at
    their own directions and incident angles (:func:`in_plane_samples`)."""
    return png_bytes(polar_figure(table, result, theta_i_deg=theta_i_deg, measured=measured))


#: How far (degrees) a sample's view may be from its plane of incidence and still be
#: drawn in it, and the fewest samples at one incident angle that make a curve of dots.
IN_PLANE_DEG = 1.0
IN_PLANE_MIN = 3
#: The most incident angles a polar plot draws (more, and its colours blur).
POLAR_MOST = 6
#: A light this close to the normal (degrees) is on it, for the plane of incidence.
OVERHEAD_DEG = 0.1


def in_plane_samples(measured: Measurements) -> dict[float, tuple[np.ndarray, np.ndarray]]:
    """A sample list's samples in the plane of incidence (the view within
    :data:`IN_PLANE_DEG` of it), by incident angle (degrees, to 0.1): each as
    ``(theta_o, rgb)``, theta_o signed as the polar plot draws it (radians; > 0 on the
    far side of the normal from the light, < 0 back towards it). At most
    :data:`POLAR_MOST` angles of :data:`IN_PLANE_MIN` samples or more, spread evenly
    over their range; empty where there are none. A light within
    :data:`OVERHEAD_DEG` of the normal is on it: every view is in a plane with it, drawn
    forward."""
    wi, wo = np.asarray(measured.wi, float), np.asarray(measured.wo, float)
    theta_i = np.degrees(np.arccos(np.clip(wi[:, 2], -1.0, 1.0)))
    # the plane's forward direction along the surface: away from the light, or along
    # the view where the light is on the normal (any plane holds it)
    across = -wi[:, :2]
    norm = np.linalg.norm(across, axis=1)
    overhead = norm < np.sin(np.radians(OVERHEAD_DEG))  # its azimuth says nothing there
    across[overhead] = wo[overhead, :2]
    theta_i[overhead] = 0.0  # one group, however near the normal each is
    norm = np.linalg.norm(across, axis=1)
    u = across / np.where(norm > 0, norm, 1.0)[:, None]
    along = np.sum(wo[:, :2] * u, axis=1)
    off = np.abs(wo[:, 0] * u[:, 1] - wo[:, 1] * u[:, 0])  # the view's part out of the plane
    flat = (off <= np.sin(np.radians(IN_PLANE_DEG))) & (wo[:, 2] > 0)
    groups: dict[float, np.ndarray] = {}
    keys = np.round(theta_i[flat], 1)
    idx = np.flatnonzero(flat)
    for key in np.unique(keys):
        members = idx[keys == key]
        if members.size >= IN_PLANE_MIN:
            groups[float(key)] = members
    if len(groups) > POLAR_MOST:
        ordered = sorted(groups)
        keep = {ordered[int(round(k))] for k in np.linspace(0, len(ordered) - 1, POLAR_MOST)}
        groups = {k: v for k, v in groups.items() if k in keep}
    return {k: (np.arctan2(along[v], wo[v, 2]), np.asarray(measured.rgb[v], float))
            for k, v in sorted(groups.items())}


def polar_figure(table: MerlTable, result: FitResult | dict, *,
                 theta_i_deg=POLAR_THETA_I, measured: Measurements | None = None) -> Figure:
    """:func:`polar`'s figure."""
    result = as_result(result)
    samples = (in_plane_samples(measured) if measured is not None and _on_samples(result)
               else {})
    if samples:
        theta_i_deg = tuple(samples)
    theta_o = np.radians(np.linspace(-89.0, 89.0, 357))
    theta_i = np.radians(np.asarray(theta_i_deg, dtype=float))[:, None]
    wi = np.stack(np.broadcast_arrays(-np.sin(theta_i), 0.0, np.cos(theta_i) + 0 * theta_o), -1)
    wo = np.broadcast_to(
        np.stack([np.sin(theta_o), np.zeros_like(theta_o), np.cos(theta_o)], axis=-1), wi.shape
    )
    if samples:  # the samples themselves, each at its own directions
        dots = [samples[k] for k in theta_i_deg]
    else:  # the table's bins along the plane
        looked_up = table.lookup(wi, wo)  # (n_theta_i, n_theta_o, 3)
        dots = [(theta_o, looked_up[k]) for k in range(len(theta_i_deg))]
    fitted = evaluate(result, wi, wo)
    values = np.concatenate([*(rgb.ravel() for _, rgb in dots), fitted.ravel()])
    values = values[np.isfinite(values) & (values > 0)]
    top = np.ceil(np.log10(values.max())) if values.size else 1.0
    bottom = max(np.floor(np.log10(values.min())) if values.size else -3.0, top - 5)

    def radius(v):
        return np.clip(np.log10(np.where(v > 0, v, np.nan)) - bottom, 0.0, None)

    fig = Figure(figsize=(16.0, 4.0))
    # Half discs placed by hand: matplotlib centres the wedge (height r) in a square
    # box of side 2r, so the disc's centre is r/2 above the box's bottom, which
    # hangs below the figure. Here r = 1.9 in, centres 0.45 in above the bottom.
    colours = _discrete_colours("viridis", len(theta_i_deg))
    ticks = np.arange(0, top - bottom + 1)
    for c, (name, _) in enumerate(CHANNELS):
        ax = fig.add_axes((0.02 + c * 0.28, (0.45 - 0.95) / 4.0, 3.8 / 16.0, 3.8 / 4.0),
                          projection="polar")
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)
        ax.set_thetamin(-90)
        ax.set_thetamax(90)
        for k, (ti, colour) in enumerate(zip(theta_i_deg, colours, strict=True)):
            at, rgb = dots[k]
            ax.plot(at, radius(rgb[:, c]), "o", ms=4.0 if samples else 2.2, color=colour,
                    alpha=0.8 if samples else 0.5, mec="none")
            ax.plot(theta_o, radius(fitted[k, :, c]), "-", lw=1.4, color=colour,
                    label=f"θi = {ti:g}°")
            ax.plot([-np.radians(ti)] * 2, [0, top - bottom], ls=":", lw=1, color=colour)
        ax.set_rticks(ticks)
        # the one radial scale, labelled once: the neighbours' labels would collide
        ax.set_yticklabels([f"$10^{{{int(bottom + t)}}}$" for t in ticks] if c == 0
                           else [], fontsize=8)
        ax.set_rlim(0, top - bottom)
        ax.set_rlabel_position(-90)
        ax.set_thetagrids(range(-90, 91, 30), [f"{d}°" for d in range(-90, 91, 30)],
                          fontsize=8)
        # above the half disc (its top is at 0.75 of the box), clear of the -30° label
        ax.text(0.5, 0.83, f"{name} channel", transform=ax.transAxes, ha="center",
                va="bottom", fontsize=12, color=CHANNELS[c][1], fontweight="bold")
    fig.legend(
        handles=ax.get_legend_handles_labels()[0]
        + [Line2D([], [], ls="none", marker="o", color="0.3", label="measured"),
           Line2D([], [], color="0.3", label="fit"),
           Line2D([], [], color="0.3", ls=":", label="incident direction")],
        loc="upper left", bbox_to_anchor=(0.85, 0.9), fontsize=9,
        title="incident angle", title_fontsize=9,
    )
    fig.text(0.85, 0.06, "radius: f_r (1/sr, log),\none scale for R, G, B\nθo < 0: back "
             "towards\nthe light; > 0: forward", fontsize=9, va="bottom")
    if samples:
        n_flat = sum(len(at) for at, _ in samples.values())
        note = (f"\na sample list: {n_flat:,} of its {measured.n:,} samples lie in their plane "
                f"of incidence at these {len(samples)} incident angles, each drawn at its "
                "own directions")
    else:
        note = _few_samples(table, result, "the plane of incidence")
    fig.suptitle(f"{_title(table, result)}  |  BRDF in the plane of incidence, per channel"
                 f"{note}", fontsize=12)
    return fig


def _discrete_colours(name: str, n: int):
    from matplotlib import colormaps

    return [colormaps[name](x) for x in np.linspace(0.05, 0.85, n)]


# -- one page per fit -----------------------------------------------------------------


def report(table: MerlTable, result: FitResult | dict, *,
           exposure_ev: float | None = None, measured: Measurements | None = None) -> bytes:
    """One page: the parameters with their standard errors and undetermined flags,
    every error metric, the spheres (at ``exposure_ev``; by default where the verdict
    judged the key light, :func:`page_exposure_ev`), the phi_d = 90 deg slices and the
    error map. ``measured``: the sample list ``result`` was fitted to (``table`` its
    binned table), whose samples fill few of the spheres' pixels: each sample fitted
    against measured (``brdffit.view.sample_plot``) and the fit's own spheres are drawn
    in their place."""
    result = as_result(result)
    exposure_ev = check_exposure_ev(page_exposure_ev(table) if exposure_ev is None
                                    else exposure_ev)
    # the head as tall as its longest column of text (10.5 pt lines, ~0.19 in each):
    # a layered model's parameters and their reasons ran into the spheres' title
    params, metrics = summary_lines(result)
    head_in = max(2.6, 0.19 * max(len(params), len(metrics)) + 0.6)
    fig = Figure(figsize=(14.0, 16.9 + head_in), layout="constrained")
    head, sph, sli, err = fig.subfigures(4, 1, height_ratios=[head_in, 9.0, 3.6, 4.2])
    _draw_summary(head, result, params, metrics)
    of_samples = measured is not None and _on_samples(result)
    if of_samples:
        _draw_samples_and_fit(sph, table, measured, result, exposure_ev)
    else:
        # smaller row labels: three lines of 10 pt ran into the next row's at this size
        _, checkered = _draw_spheres(sph, table, result, size=160, exposure_ev=exposure_ev,
                                     label_size=8.5)
        sph.suptitle(f"sphere renders, one exposure for table and fit"
                     f"{_exposure_words(exposure_ev)}{_CHECKERED if checkered else ''}"
                     f"{_few_samples(table, result, 'the spheres and slices')}", fontsize=11)
    phi_d = _fullest_phi_d(table) if of_samples else 90.0
    _draw_slices(sli, table, result, (1.0, 30.0, 60.0, 80.0), (phi_d,))
    sli.suptitle(f"slices at φd = {phi_d:.1f}°, where the samples' "
                 "bins are most: fit (lines), and the samples' bins on them (dots)"
                 if of_samples else "slices: measured (dots), fit (lines)", fontsize=11)
    _draw_error_map(err, table, result)
    err.suptitle("error per bin, averaged over φd and RGB; grey: no measured bin", fontsize=11)
    fig.suptitle(_title(table, result), fontsize=14, fontweight="bold")
    return png_bytes(fig)


def _draw_samples_and_fit(fig, table: MerlTable, measured: Measurements, result: FitResult,
                          exposure_ev: float) -> None:
    """A sample list's report, where a table's has its spheres: each sample fitted
    against measured, and the fit's spheres under the three lights (the measured ones
    would be mostly unmeasured bins)."""
    from brdffit.view import sample_plot

    top, bottom = fig.subfigures(2, 1, height_ratios=[5.0, 4.0])
    shown, not_drawn = sample_plot.draw(top, measured, result)
    held = result.error.get("held_out_log_rmse")
    words = [f"each sample, fitted against measured: {shown:,} of {measured.n:,} drawn "
             "(a random subset)" if shown < measured.n
             else f"each of the {measured.n:,} samples, fitted against measured"]
    if held is not None:
        words.append(f"held-out log_rmse {held:.3g}")
    if not_drawn:
        words.append(f"{not_drawn:,} with a value <= 0 or below the horizon not drawn")
    top.suptitle("; ".join(words) + "; the verdict judges the held-out samples", fontsize=11)
    background = np.array(to_rgb(SPHERE_BACKGROUND))
    size = 160
    axes = bottom.subplots(1, len(SPHERE_LIGHTS))
    for ax, (label, light) in zip(axes, SPHERE_LIGHTS, strict=True):
        _, fitted, coverage, _ = sphere_images(table, result, light, size,
                                               with_measured=False)
        ax.imshow(_composite(fitted, coverage, background, exposure_ev),
                  interpolation="bilinear")
        ax.add_patch(Circle(((size - 1) / 2, (size - 1) / 2), size / 2, fill=False, lw=0.8,
                            ec="0.65"))
        ax.set_title(label.replace("\n", " "), fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    bottom.suptitle(f"the fit ({result.model}) rendered on a sphere"
                    f"{_exposure_words(exposure_ev)}", fontsize=11)


def summary_lines(result: FitResult) -> tuple[list[str], list[str]]:
    """The parameter lines (``value ± error``, flags) and the metric lines of a fit."""
    u = result.uncertainty or {}
    se, flags = u.get("std_error", {}), u.get("undetermined", {})
    at_bound = u.get("at_bound", {})
    params = []
    # every name then its values in one column: "clearcoat_roughness0.1284" ran together
    width = max([6, *(len(n) for n in result.params)])
    for name, v in result.params.items():
        vals = v if isinstance(v, list) else [v]

        def listed(d, default, name=name, n=len(vals)):
            x = d.get(name, [default] * n)
            return x if isinstance(x, list) else [x]

        keys = [name] if not isinstance(v, list) else [f"{name}[{i}]" for i in range(len(vals))]
        parts = []
        for x, e, b, f, k in zip(vals, listed(se, None), listed(at_bound, False),
                                 listed(flags, False), keys, strict=True):
            e = None if error_measures_nothing(u.get("why", {}).get(k)) else e
            text = f"{x:.4g}" + (" (bound)" if b else "" if e is None else f" ± {e:.2g}")
            parts.append(text + (" ?" if f else ""))
        params += wrap_values(f"{name:<{width}} ", parts)
    # wrapped as the values are: a long reason ran into the errors column beside it
    params += [line for k, why in u.get("why", {}).items()
               for line in textwrap.wrap(f"? {k}: {why}", PARAM_LINE_CHARS - 2,
                                         initial_indent="  ", subsequent_indent="      ")]
    params += [f"  {k} ~ {', '.join(v)} (|corr| > 0.95)"
               for k, v in u.get("strongly_correlated", {}).items()]
    e = result.error

    def g(key, fmt=".4g"):
        x = e.get(key)
        return "n/a" if x is None or not np.isfinite(x) else format(x, fmt)

    held = "held_out_log_rmse" in e
    basis = (result.quality or {}).get("basis", "sphere")
    metrics = [f"log_rmse        {g('log_rmse')}",
               *([f"  held out      {g('held_out_log_rmse')} ± {g('held_out_log_rmse_se', '.2g')}"]
                 if held else []),
               f"cube_root_rmse  {g('cube_root_rmse')}",
               f"rmse_cos        {g('rmse_cos')} 1/sr",
               f"rel_peak_error  {g('rel_peak_error')}",
               f"{'held-out' if basis == 'held_out' else 'sphere'} PSNR"
               f"{' ' if basis == 'held_out' else '   '}{g('psnr_db', '.1f')} dB",
               *_looks_lines(result.quality),
               f"loss {result.loss}, {result.result}, {result.steps} steps, "
               f"{result.samples['used']:,} of {result.samples['usable']:,} "
               f"{'samples' if _on_samples(result) else 'bins'}"]
    return params, metrics


def _on_samples(result: FitResult) -> bool:
    """A fit of a sample list at its own directions (``brdffit.fitting.samples``)."""
    return (result.input or {}).get("fitted_at") == "samples"


def _looks_lines(look: dict | None) -> list[str]:
    """The verdict, its brightness and colour figures, and the first next step, for the
    report's metrics column (a result stored before brdffit.fit/2 has the verdict only)."""
    if not look:
        return []
    lines = [f"looks           {look['verdict']}"]
    stops, (shift, where) = judged_brightness(look), judged_colour(look)
    if isinstance(stops, int | float):
        shown = " as displayed" if "displayed_brightness_stops" in look else ""
        lines.append(f"brightness      {stops:+.2f} stops{shown}")
    if isinstance(shift, int | float):
        lines.append(f"colour          CIEDE2000 {shift:.1f}{' ' + where if where else ''}")
    steps = look.get("next") or []
    # the first step, and where it says what nothing here can follow, the first one to
    # run after it: "nothing here" alone hid a step the CLI printed beneath it
    shown = steps[:1]
    if steps and steps[0]["try"].startswith("nothing here"):
        shown += [s for s in steps[1:] if not s["try"].startswith("nothing here")][:1]
    for i, step in enumerate(shown):
        gain = "" if step.get("gain_db") is None else f" ({step['gain_db']:+.1f} dB)"
        # wrapped, not cut: "--starts 8 --m…" could not be copied from the page
        lines += textwrap.wrap(f"{'next' if i == 0 else 'else'}: {step['try']}{gain}", 44,
                               subsequent_indent="      ", break_on_hyphens=False,
                               break_long_words=False)
    return lines


#: Characters a parameter line of the report's header may take before its values
#: wrap: past it, the line runs into the errors column beside it.
PARAM_LINE_CHARS = 60


def wrap_values(label: str, parts: list[str]) -> list[str]:
    """``label`` then ``parts`` joined by commas, wrapped under the first value where a
    line would pass :data:`PARAM_LINE_CHARS` (three bound RGB values do)."""
    lines, line, fresh = [], label, True
    for i, part in enumerate(parts):
        piece = part + ("," if i < len(parts) - 1 else "")
        if not fresh and len(line) + 2 + len(piece) > PARAM_LINE_CHARS:
            lines.append(line)
            line, fresh = " " * len(label), True
        line += piece if fresh else "  " + piece
        fresh = False
    return lines + [line]


def _draw_summary(fig, result: FitResult, params: list[str], metrics: list[str]) -> None:
    """The report's head: ``params`` and ``metrics`` (:func:`summary_lines`), and the
    correlation matrix."""
    ax_p, ax_m, ax_c = fig.subplots(1, 3, width_ratios=[1.7, 1.0, 0.9])
    for ax, title, lines in ((ax_p, "parameters ± standard error   (? = undetermined)", params),
                             (ax_m, "errors (every sample)" if _on_samples(result)
                              else "errors (full table)", metrics)):
        ax.set_axis_off()
        ax.set_title(title, fontsize=11, loc="left")
        ax.text(0.0, 1.0, "\n".join(lines), va="top", ha="left", family="monospace",
                fontsize=10.5, transform=ax.transAxes)
    _draw_correlation(fig, ax_c, result)


def _draw_correlation(fig, ax, result: FitResult) -> None:
    """The parameters' correlation matrix (``FitResult.uncertainty``): a pair near ±1
    trades off; grey where a parameter has no error (at a bound, undetermined)."""
    u = result.uncertainty or {}
    names = u.get("entries")
    if not names:
        ax.set_axis_off()
        ax.set_title("no uncertainty for this fit", fontsize=10)
        return
    c = np.array([[np.nan if x is None else x for x in row] for row in u["correlation"]],
                 dtype=float)
    m = ax.imshow(np.ma.masked_invalid(c), cmap=_with_bad("RdBu_r"), vmin=-1, vmax=1,
                  interpolation="nearest")
    ticks = range(len(names))
    # smaller labels for more entries: 14 of standard_surface_sheen's overlapped at 7 pt
    size = 7.0 if len(names) <= 10 else max(4.5, 70.0 / len(names))
    ax.set_xticks(ticks, names, rotation=90, fontsize=size)
    ax.set_yticks(ticks, names, fontsize=size)
    ax.set_title("parameter correlation\n(grey: bound or undetermined)", fontsize=8)
    fig.colorbar(m, ax=ax, shrink=0.8, ticks=[-1, 0, 1])


# -- all of them --------------------------------------------------------------------

RENDERERS: dict[str, Callable[[MerlTable, FitResult], bytes]] = {
    "slices": slices, "error_map": error_map, "spheres": spheres, "polar": polar,
    "report": report,
}


def render(kind: str, table: MerlTable, result: FitResult | dict,
           exposure_ev: float = 0.0, measured: Measurements | None = None) -> bytes:
    """The plot called ``kind`` (one of :data:`KINDS`) as PNG bytes; ``exposure_ev``
    (stops) for the kinds with sphere renders (``brdffit.view.kinds.EXPOSED_KINDS``), refused for
    the others rather than ignored. ``measured``: the sample list ``table`` was binned
    from, which the report draws (:func:`report`)."""
    if kind not in RENDERERS:
        raise ValueError(f"unknown plot kind {kind!r}; choose one of {', '.join(KINDS)}")
    more = ({"measured": measured} if kind in ("report", "polar") and measured is not None
            else {})
    if exposure_ev:
        if (why := exposure_refused(kind, exposure_ev)) is not None:
            raise ValueError(why)
        return RENDERERS[kind](table, as_result(result), exposure_ev=exposure_ev, **more)
    return RENDERERS[kind](table, as_result(result), **more)


def save_all(table: MerlTable, result: FitResult | dict, directory: str | os.PathLike,
             kinds=KINDS, measured: Measurements | None = None) -> list[str]:
    """Write ``<directory>/<kind>.png`` for each kind; returns the paths.

    Each file is rendered first, then written beside its place and renamed over
    it (``brdffit.io.atomic``): a plot that fails to render leaves no file (not a
    0-byte one), a reader never sees half a PNG, and the file has the permissions
    the umask gives, as any file the user writes.
    """
    os.makedirs(directory, exist_ok=True)
    paths = []
    for kind in kinds:
        path = os.path.join(directory, f"{kind}.png")
        atomic.write_bytes(path, render(kind, table, result, measured=measured),
                           prefix=f".{kind}.")
        paths.append(path)
    if "spheres" in kinds and (ev := page_exposure_ev(table)) != 0.0:
        path = os.path.join(directory, JUDGED_SPHERES)  # its rows say where each was judged
        atomic.write_bytes(path, render("spheres", table, result, exposure_ev=ev),
                           prefix=".spheres_judged.")
        paths.append(path)
    return paths


def page_exposure_ev(table: MerlTable) -> float:
    """The exposure (stops) of a one-page report's spheres: where the verdict judged the
    key light, when that is :data:`JUDGED_APART_EV` or more from the one exposure for
    every material (0). A dark or near-mirror material's report showed two black
    spheres with a dot each, and what the verdict compared was in another file."""
    ev = judged_ev(table, SPHERE_LIGHTS[0][1])
    if ev is None or abs(ev) < JUDGED_APART_EV:
        return 0.0
    return float(np.clip(ev, *EXPOSURE_EV_RANGE))


#: The spheres at the key light's judged exposure, written beside ``spheres.png``
#: where that is this many stops or more from it: a dark fabric's, judged at +6 EV,
#: is near black in ``spheres.png``, and a near-mirror's halo (judged at +7 to +11 EV)
#: is not there at all, so what the verdict compared could not be seen.
JUDGED_APART_EV = 2.0
JUDGED_SPHERES = "spheres_judged.png"


# -- auto's ranking ----------------------------------------------------------------------

#: Bar colours of :func:`ranking` by the row's status in the selection.
RANKING_COLOURS = {"chosen": "#2ca02c", "within tolerance": "#98df8a",
                   "under budget": "#98df8a", "looks worse": "#fdd0a2", "too far": "#c7c7c7"}


def ranked_psnr(row: dict, rule: str | None) -> float | None:
    """The PSNR (dB) :func:`ranking` draws for a candidate's ``row``: under the render
    rule the one it ranked by (``views_psnr_db``, the render loss's eight lights, where
    measured), else the sphere's two lights (``psnr_db``); None where not finite. The
    plot drew ``psnr_db`` under the render rule too: ggx at 35.7 dB beside a reason
    that said 34.5."""
    p = row.get("views_psnr_db") if rule == "render_psnr_db" else None
    p = row.get("psnr_db") if p is None else p
    return float(p) if isinstance(p, int | float) and np.isfinite(p) else None


def ranking(selection: dict) -> bytes:
    """``model="auto"``'s choice as a picture: each candidate's log_rmse (cheapest at
    the top), the best error and the tolerance line the chosen one had to be within,
    and each candidate's sphere PSNR with its verdict; the reason under it. Where the
    render rule chose (the render loss: ``selection["rule"]``), the PSNR is the one it
    ranked by (``views_psnr_db``, the render loss's eight lights) with the 0.5 dB the
    chosen one had to be within, and the log_rmse axis has no tolerance line: the
    tolerance played no part.

    ``selection`` is a chosen fit's ``selection`` (``FitResult.selection``), so a
    stored result draws it as well as a fresh one.
    """
    import textwrap

    rows = selection["ranking"]
    fitted = [r for r in rows if r["status"] != "failed"]
    rule = selection.get("rule")
    by_look = rule == "render_psnr_db"

    n = len(rows)
    fig = Figure(figsize=(10, 2.2 + 0.42 * n), layout="constrained")
    ax_err, ax_psnr = fig.subplots(1, 2, sharey=True, width_ratios=(3, 2))
    y = np.arange(n)
    for i, r in enumerate(rows):
        if r["status"] == "failed":
            why = textwrap.shorten(str(r.get("message", r.get("result", ""))), 60)
            ax_err.text(0.01, i, f"failed: {why}", va="center", fontsize=8,
                        transform=ax_err.get_yaxis_transform(), color="#d62728")
            continue
        colour = RANKING_COLOURS.get(r["status"], "#c7c7c7")
        ax_err.barh(i, r["log_rmse"], color=colour, edgecolor="#333333", linewidth=0.5)
        ax_err.text(r["log_rmse"], i, f" {r['log_rmse']:.3g}"
                    + ("" if r.get("converged", True) else " (not converged)"),
                    va="center", fontsize=8, zorder=4,  # over the tolerance lines
                    bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.5, "alpha": 0.8})
        psnr = ranked_psnr(r, rule)
        if psnr is not None:
            ax_psnr.barh(i, psnr, color=colour, edgecolor="#333333", linewidth=0.5)
            ax_psnr.text(psnr, i, f" {psnr:.1f} dB" + (f", {r['verdict']}" if r.get("verdict")
                                                       else ""), va="center", fontsize=8)
    if fitted:
        best = min(r["log_rmse"] for r in fitted)
        limit = float(np.hypot(best, selection["tolerance"]))
        worst = max(r["log_rmse"] for r in fitted)
        # the axis holds the bars, and the tolerance line where it is near them: a
        # tolerance far beyond every candidate (--tolerance 10) is said at the edge, as
        # is one where every candidate fits exactly (log_rmse 0, an axis of width 0)
        right = 1.3 * (max(worst, min(limit, 3 * worst)) if worst > 0 else limit) or 1.0
        ax_err.set_xlim(0, right)
        ax_err.axvline(best, color="#333333", linewidth=1)
        # under the render rule the lowest log_rmse is reported, not what was ranked: a
        # "best" line there stood beside a grey "too far" bar (green-fabric's ggx)
        lines = [Line2D([], [], color="#333333", linewidth=1,
                        label="lowest log_rmse (not ranked by)" if by_look else "best")]
        words = f"best + tolerance {selection['tolerance']:g} (in quadrature)"
        if by_look:
            pass  # the render rule chose by the PSNR: its window is drawn there
        elif limit <= right:
            # named in the legend: written beside the line it ran past the axes, or over
            # the best line's own label
            ax_err.axvline(limit, color="#333333", linewidth=1, linestyle="--")
            lines.append(Line2D([], [], color="#333333", linewidth=1, linestyle="--",
                                label=words))
        else:
            ax_err.text(1.0, -0.6, f"{words}: {limit:.3g}, beyond the axis \u2192 ",
                        fontsize=7, va="center", ha="right",
                        transform=ax_err.get_yaxis_transform())
        if selection.get("budget") is not None:
            ax_err.axvline(selection["budget"], color="#1f77b4", linewidth=1, linestyle=":")
        top = max((ranked_psnr(r, rule) or 0.0) for r in fitted)
        psnrs = [p for r in fitted if (p := ranked_psnr(r, rule)) is not None]
        # from a little below the lowest (and the poor line), not 0: 25 against 29 dB
        # looked alike on an axis from 0; the verdict's lines drawn
        low = max(0.0, 5.0 * np.floor((min([*psnrs, POOR[0]]) - 3.0) / 5.0))
        # the good line on the axis too: its label ran past the axis (chrome's ~23 dB)
        ax_psnr.set_xlim(low, max(top + 0.35 * (top - low), low + 1.0, GOOD[0] + 4.0))
        # each word on its own side of its line: 8 dB apart on a short axis, the two ran
        # into each other
        for level, said, side in ((POOR[0], "poor below", "right"),
                                  (GOOD[0], "good from", "left")):
            ax_psnr.axvline(level, color="#888888", linewidth=0.8, linestyle=":")
            words = f"{said} {level:g} dB "if side == "right" else f" {said} {level:g} dB"
            ax_psnr.text(level, -1.22 if by_look else -0.72, words, fontsize=7, va="center",
                         ha=side, color="#444444")
        if by_look and top > 0:
            ax_psnr.axvline(top, color="#333333", linewidth=1)
            ax_psnr.axvline(top - ALIKE_DB, color="#333333", linewidth=1, linestyle="--")
            # named on a row of their own above the bars, under the verdict lines' row: a
            # legend inside the axes covered the bottom bar (the chosen one), and their
            # words on the verdict lines' row ran over them where the best is near 28 dB
            ax_psnr.text(top, -0.72, " best", fontsize=7, va="center", ha="left",
                         color="#333333")
            ax_psnr.text(top - ALIKE_DB, -0.72, f"best − {ALIKE_DB:g} dB ", fontsize=7,
                         va="center", ha="right", color="#333333")
    ax_err.set_yticks(y, [f"{r['model']} ({r['n_params']})" for r in rows])
    ax_err.set_ylim(n - 0.5, -1.5 if by_look else -1.0)  # a row for the lines' words
    ax_err.set_xlabel("log_rmse (reported, not ranked by)" if by_look
                      else "log_rmse (lower is better)")
    ax_psnr.set_xlabel("sphere PSNR under the render loss's eight lights, dB (higher is "
                       "better)" if by_look else "sphere PSNR, dB (higher is better)")
    ax_err.set_title("candidates in auto's order (parameter count)", fontsize=10)
    # the verdict weighs brightness and colour too: 30.0 dB "visible" beside 28.2 dB
    # "good" is a brightness the PSNR does not show (each fit's quality says which)
    ax_psnr.set_title("how each looks: PSNR, and the verdict\n(which also judges brightness "
                      "and colour)", fontsize=9)
    shown = dict.fromkeys(r["status"] for r in fitted if r["status"] in RANKING_COLOURS)
    handles = [Patch(facecolor=RANKING_COLOURS[s], edgecolor="#333333", linewidth=0.5,
                     label=s) for s in shown] + (lines if fitted else [])
    if handles:
        ax_err.legend(handles=handles, loc="lower right", fontsize=7, framealpha=0.9)
    table = source_name(str(selection.get("table") or "table"))
    fig.suptitle(f"{table}: auto chose {selection['chosen']}", fontsize=12)
    reason = selection["reason"].replace("$", r"\$")
    fig.text(0.01, 0.0, textwrap.fill(reason, 150), fontsize=8, va="top", ha="left")
    return _png_with_footer(fig)


def _png_with_footer(fig: Figure) -> bytes:
    """As :func:`png_bytes`, keeping text placed below the axes (the reason) in the image."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, facecolor="white", bbox_inches="tight",
                pad_inches=0.15)
    return buf.getvalue()


def save_report(table: MerlTable, report, directory: str | os.PathLike,
                kinds=KINDS, measured: Measurements | None = None) -> list[str]:
    """The plots of a :class:`brdffit.request.FitReport`'s chosen fit
    (:func:`save_all`; ``measured``, the sample list ``table`` was binned from), and for
    ``auto`` the ranking of every candidate (``ranking.png``, :func:`ranking`)."""
    paths = save_all(table, report.chosen_fit, directory, kinds, measured=measured)
    selection = report.chosen_fit.selection
    if selection is not None:
        path = os.path.join(directory, "ranking.png")
        atomic.write_bytes(path, ranking(selection), prefix=".ranking.")
        paths.append(path)
    return paths
