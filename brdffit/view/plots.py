"""How good is a fit? Four pictures of a table and its fit, each as PNG bytes.

- :func:`slices`: measured vs fitted f_r against theta_h, a panel per theta_d,
  at phi_d = 90 deg (the view of Ngan et al. 2005), log f_r;
- :func:`error_map`: the fit's per-bin error over (theta_h, theta_d), the very
  residual that ``log_rmse`` aggregates (``brdffit.fitting.loss``), and its sign;
- :func:`spheres`: table and fit rendered on a sphere under two lights, with the
  ratio of the two images;
- :func:`polar`: f_r in the plane of incidence for a few incident angles.

The measured table is read by its reference nearest-bin lookup
(:meth:`MerlTable.lookup`), the fit is evaluated by its model in JAX; unmeasured
bins show as grey, never as zero. Figures are built on ``matplotlib.figure.Figure``
with the Agg canvas, not ``pyplot``: no global state, no display, safe in threads
and worker processes.

theta_h axes use a square-root scale: that is the MERL table's own spacing, so
the few degrees around the specular peak get as much room as the rest.
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from brdffit import extras, models, runtime

try:
    from matplotlib.colors import to_rgb
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle
except ModuleNotFoundError:
    raise extras.MissingExtraError("brdffit.view.plots", "plots", ("matplotlib",)) from None

from brdffit.fitting.result import FitResult
from brdffit.io.angles import (
    N_PHI_D,
    N_THETA_D,
    N_THETA_H,
    bin_centres,
    half_diff_to_bins,
    half_diff_to_dirs,
)
from brdffit.io.grid import bin_grid
from brdffit.io.merl import MerlTable
from brdffit.view.render import LIGHTS, radiance, sphere_disc, tonemap

KINDS = ("slices", "error_map", "spheres", "polar")

CHANNELS = (("R", "#d62728"), ("G", "#2ca02c"), ("B", "#1f77b4"))
#: Rec. 709 luminance weights, for the one-curve-per-angle plots.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
NO_DATA = "#b0b0b0"
DPI = 110


# -- shared pieces ------------------------------------------------------------------


def _as_result(result: FitResult | dict) -> FitResult:
    return result if isinstance(result, FitResult) else FitResult.from_dict(result)


@eqx.filter_jit
def _model_values(model, params, wi, wo):
    return model(params, wi, wo)


@runtime.in_float64
def evaluate(result: FitResult | dict, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The fitted model at direction pairs (..., 3) -> f_r (..., 3); NaN below the horizon.

    Compiled once per (model, batch shape): each plot calls it with fixed shapes
    (all bins above the horizon, all pixels), whatever the table's mask.
    """
    r = _as_result(result)
    model = models.get(r.model)
    params = {k: jnp.asarray(v) for k, v in r.param_arrays().items()}
    f = np.asarray(_model_values(model, params, jnp.asarray(wi), jnp.asarray(wo)),
                   dtype=np.float64)
    above = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    return np.where(above[..., None], f, np.nan)


def _title(table: MerlTable, result: FitResult) -> str:
    name = os.path.basename(table.source) or table.source
    # A table's name is the uploader's text: matplotlib would parse "$...$" in it as
    # math, and fail on an unbalanced one. An escaped dollar is a literal dollar.
    name = name.replace("$", r"\$")
    e = result.error.get("log_rmse")
    return f"{name}: {result.model} fit, log_rmse " + ("n/a" if e is None else f"{e:.3g}")


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, facecolor="white")
    return buf.getvalue()


def _sqrt_axis(ax, axis: str = "x", ticks=(0, 1, 5, 10, 20, 40, 60, 90)) -> None:
    """Square-root degree axis: the table's theta_h spacing."""
    functions = (lambda d: np.sqrt(np.maximum(d, 0.0)), lambda s: np.square(s))
    if axis == "x":
        ax.set_xscale("function", functions=functions)
        ax.set_xlim(0, 90)
        ax.set_xticks(ticks)
    else:
        ax.set_yscale("function", functions=functions)
        ax.set_ylim(0, 90)
        ax.set_yticks(ticks)


def _theta_h_edges_deg() -> np.ndarray:
    return (np.arange(N_THETA_H + 1) / N_THETA_H) ** 2 * 90.0


# -- slices -------------------------------------------------------------------------


def slices(
    table: MerlTable, result: FitResult | dict, *, theta_d_deg=(1.0, 30.0, 60.0, 80.0),
    phi_d_deg: float = 90.0,
) -> bytes:
    """Measured (dots) and fitted (lines) f_r against theta_h, one panel per theta_d."""
    result = _as_result(result)
    i_th = np.arange(N_THETA_H)
    _, i_tds, i_pd = half_diff_to_bins(
        np.zeros(len(theta_d_deg)), np.radians(theta_d_deg), np.radians(phi_d_deg)
    )
    i_pd = int(np.ravel(i_pd)[0])
    i_tds = np.atleast_1d(i_tds)
    theta_h, theta_d, phi_d = bin_centres(i_th[None, :], i_tds[:, None], i_pd)
    theta_h, theta_d, phi_d = np.broadcast_arrays(theta_h, theta_d, phi_d)
    fitted_all = evaluate(result, *half_diff_to_dirs(theta_h, theta_d, phi_d))
    fig = Figure(figsize=(12.5, 4.0), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(theta_d_deg), sharey=True))
    lo, hi = np.inf, 0.0
    for p, (ax, i_td) in enumerate(zip(axes, i_tds, strict=True)):
        fitted = fitted_all[p]
        measured = np.where(table.mask[i_th, i_td, i_pd], table.rgb[:, i_th, i_td, i_pd], np.nan).T
        x = np.degrees(theta_h[p])
        for c, (_, colour) in enumerate(CHANNELS):
            ax.plot(x, measured[:, c], "o", ms=3.2, color=colour, alpha=0.55, mec="none")
            ax.plot(x, fitted[:, c], "-", lw=1.5, color=colour)
        for v in (measured, fitted):
            v = v[np.isfinite(v) & (v > 0)]
            if v.size:
                lo, hi = min(lo, v.min()), max(hi, v.max())
        ax.set_yscale("log")
        _sqrt_axis(ax)
        ax.grid(True, which="major", alpha=0.3)
        ax.set_title(f"θd = {np.degrees(theta_d[p, 0]):.1f}°", fontsize=11)
        ax.set_xlabel("θh (degrees, √ scale)")
    first = axes[0]
    if hi > 0:
        first.set_ylim(lo / 2, hi * 2)
    first.set_ylabel("BRDF f_r (1/sr, log scale)")
    fig.legend(
        handles=[Line2D([], [], ls="none", marker="o", color="0.3", label="measured"),
                 Line2D([], [], color="0.3", label="fit")]
        + [Line2D([], [], color=col, lw=4, label=name) for name, col in CHANNELS],
        loc="outside right upper", fontsize=9,
    )
    fig.suptitle(f"{_title(table, result)}  |  slices at φd = {phi_d_deg:g}°", fontsize=12)
    return _png(fig)


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
    result = _as_result(result)
    r = bin_residuals(table, result)
    n = np.count_nonzero(np.isfinite(r), axis=(0, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.nansum(r * r, axis=(0, 3)) / n)
        bias = np.nansum(r, axis=(0, 3)) / n
    x = _theta_h_edges_deg()
    y = np.linspace(0.0, 90.0, N_THETA_D + 1)

    fig = Figure(figsize=(12.0, 4.8), layout="constrained")
    ax_rms, ax_bias = fig.subplots(1, 2, sharey=True)
    finite_rms = rms[np.isfinite(rms)]
    vmax = float(np.percentile(finite_rms, 99.5)) if finite_rms.size else 1.0
    cmap = _with_bad("magma")
    m = ax_rms.pcolormesh(x, y, rms.T, cmap=cmap, vmin=0.0, vmax=max(vmax, 1e-6),
                          shading="flat", rasterized=True)
    fig.colorbar(m, ax=ax_rms, label="RMS residual of log(1 + f_r cos θi)", extend="max")
    ax_rms.set_title("|error| per bin (what log_rmse averages)", fontsize=11)

    finite_bias = np.abs(bias[np.isfinite(bias)])
    bmax = float(np.percentile(finite_bias, 99.5)) if finite_bias.size else 1.0
    m = ax_bias.pcolormesh(x, y, bias.T, cmap=_with_bad("RdBu_r"), vmin=-max(bmax, 1e-6),
                           vmax=max(bmax, 1e-6), shading="flat", rasterized=True)
    fig.colorbar(m, ax=ax_bias, label="mean residual: fit − measured", extend="both")
    ax_bias.set_title("sign: red = fit too bright, blue = too dark", fontsize=11)

    for ax in (ax_rms, ax_bias):
        _sqrt_axis(ax)
        ax.set_facecolor(NO_DATA)
        ax.set_xlabel("θh (degrees, √ scale)")
    ax_rms.set_ylabel("θd (degrees)")
    ax_rms.set_yticks([0, 15, 30, 45, 60, 75, 90])
    fig.suptitle(f"{_title(table, result)}  |  averaged over φd and RGB; grey: no measured bin",
                 fontsize=12)
    return _png(fig)


def _with_bad(name: str):
    from matplotlib import colormaps

    return colormaps[name].with_extremes(bad=NO_DATA)


# -- spheres ------------------------------------------------------------------------

SPHERE_BACKGROUND = "#33404f"
# The lights and the sphere geometry are brdffit.view.render's: the plots show what the
# selection's PSNR measures.


def spheres(table: MerlTable, result: FitResult | dict, *, size: int = 200) -> bytes:
    """Table and fit on a sphere under two lights, and log2(fit / measured)."""
    result = _as_result(result)
    fig = Figure(figsize=(10.5, 7.0), layout="constrained")
    axes = fig.subplots(len(LIGHTS), 3)
    background = np.array(to_rgb(SPHERE_BACKGROUND))
    no_data = np.array(to_rgb(NO_DATA))
    ratio_img = None
    for row, (label, light) in enumerate(LIGHTS):
        wi, wo, inside = sphere_disc(size, light)
        lit = inside & (wi[..., 2] > 0) & (wo[..., 2] > 0)
        measured = np.zeros((size, size, 3))
        fitted = np.zeros((size, size, 3))
        measured[lit] = table.lookup(wi[lit], wo[lit])
        fitted[lit] = evaluate(result, wi, wo)[lit]  # every pixel: one compiled shape
        measured, fitted = radiance(measured, wi), radiance(fitted, wi)
        unmeasured = lit & ~np.all(np.isfinite(measured), axis=-1)
        lum_m, lum_f = measured @ LUMINANCE, fitted @ LUMINANCE
        ok = lit & ~unmeasured
        # One exposure per row, from the measured image, for both: the pictures
        # compare brightness honestly.
        typical = float(np.median(lum_m[ok])) if ok.any() else 1.0
        exposure = 0.35 / max(typical, 1e-6)
        images = []
        for rad in (measured, fitted):
            img = tonemap(np.nan_to_num(rad), exposure)
            img[~inside] = background
            images.append(img)
        images[0][unmeasured] = no_data
        eps = 1e-3 * max(typical, 1e-9)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.log2((lum_f + eps) / (lum_m + eps))
        ratio = np.where(ok, ratio, np.nan)
        for col, img in enumerate(images):
            axes[row, col].imshow(img, interpolation="nearest")
        # Under the ratio: background outside the sphere, black where unlit, grey
        # where the table has no bin; the ratio's masked pixels are transparent.
        base = np.where(inside[..., None], 0.0, background)
        base[unmeasured] = no_data
        axes[row, 2].imshow(base, interpolation="nearest")
        ratio_img = axes[row, 2].imshow(np.ma.masked_invalid(ratio), cmap="RdBu_r",
                                        vmin=-2, vmax=2, interpolation="nearest")
        axes[row, 0].set_ylabel(label, fontsize=10)
        for ax in axes[row]:  # the unlit half is black: outline the sphere
            ax.add_patch(Circle(((size - 1) / 2, (size - 1) / 2), size / 2, fill=False,
                                lw=0.8, ec="0.65"))
    for col, name in enumerate(("measured (nearest bin)", f"fit ({result.model})",
                                "log₂(fit / measured)")):
        axes[0, col].set_title(name, fontsize=11)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(ratio_img, ax=axes[:, 2], shrink=0.8, extend="both",
                 label="brightness ratio, stops (+1: fit 2× brighter)")
    fig.suptitle(f"{_title(table, result)}\nsphere renders, directional light, "
                 "camera along the normal at the centre; grey: unmeasured bin", fontsize=12)
    return _png(fig)


# -- polar --------------------------------------------------------------------------


def polar(
    table: MerlTable, result: FitResult | dict, *, theta_i_deg=(10.0, 30.0, 50.0, 70.0)
) -> bytes:
    """f_r (luminance) in the plane of incidence, log radius, per incident angle."""
    result = _as_result(result)
    theta_o = np.radians(np.linspace(-89.0, 89.0, 357))
    theta_i = np.radians(np.asarray(theta_i_deg, dtype=float))[:, None]
    wi = np.stack(np.broadcast_arrays(-np.sin(theta_i), 0.0, np.cos(theta_i) + 0 * theta_o), -1)
    wo = np.broadcast_to(
        np.stack([np.sin(theta_o), np.zeros_like(theta_o), np.cos(theta_o)], axis=-1), wi.shape
    )
    measured = table.lookup(wi, wo) @ LUMINANCE
    fitted = evaluate(result, wi, wo) @ LUMINANCE
    curves = list(zip(measured, fitted, strict=True))
    values = np.concatenate([np.ravel(c) for c in curves])
    values = values[np.isfinite(values) & (values > 0)]
    top = np.ceil(np.log10(values.max())) if values.size else 1.0
    bottom = max(np.floor(np.log10(values.min())) if values.size else -3.0, top - 5)

    def radius(v):
        return np.clip(np.log10(np.where(v > 0, v, np.nan)) - bottom, 0.0, None)

    fig = Figure(figsize=(11.0, 5.6))
    # A half disc placed by hand: matplotlib centres the wedge (height r) in a square
    # box of side 2r, so the box hangs below the figure to put the disc's centre
    # near the bottom edge. Here r = 3.6 in, centre 0.7 in above the bottom.
    ax = fig.add_axes((0.04, (0.7 - 1.8) / 5.6, 7.2 / 11.0, 7.2 / 5.6), projection="polar")
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    colours = _discrete_colours("viridis", len(theta_i_deg))
    for ti, (meas, fit), colour in zip(theta_i_deg, curves, colours, strict=True):
        ax.plot(theta_o, radius(meas), "o", ms=2.6, color=colour, alpha=0.5, mec="none")
        ax.plot(theta_o, radius(fit), "-", lw=1.6, color=colour, label=f"θi = {ti:g}°")
        ax.plot([-np.radians(ti)] * 2, [0, top - bottom], ls=":", lw=1, color=colour)
    ticks = np.arange(0, top - bottom + 1)
    ax.set_rticks(ticks)
    ax.set_yticklabels([f"$10^{{{int(bottom + t)}}}$" for t in ticks], fontsize=9)
    ax.set_rlim(0, top - bottom)
    ax.set_rlabel_position(-90)
    ax.set_thetagrids(range(-90, 91, 30), [f"{d}°" for d in range(-90, 91, 30)])
    fig.legend(
        handles=ax.get_legend_handles_labels()[0]
        + [Line2D([], [], ls="none", marker="o", color="0.3", label="measured"),
           Line2D([], [], color="0.3", label="fit"),
           Line2D([], [], color="0.3", ls=":", label="incident direction")],
        loc="upper left", bbox_to_anchor=(0.73, 0.86), fontsize=9,
        title="incident angle", title_fontsize=9,
    )
    fig.text(0.73, 0.2, "radius: f_r luminance\n(1/sr, log scale)\n\nθo < 0: back towards\n"
            "the light; > 0: forward", fontsize=9, va="bottom")
    fig.suptitle(f"{_title(table, result)}  |  BRDF in the plane of incidence", fontsize=12)
    return _png(fig)


def _discrete_colours(name: str, n: int):
    from matplotlib import colormaps

    return [colormaps[name](x) for x in np.linspace(0.05, 0.85, n)]


# -- all of them --------------------------------------------------------------------

RENDERERS: dict[str, Callable[[MerlTable, FitResult], bytes]] = {
    "slices": slices, "error_map": error_map, "spheres": spheres, "polar": polar,
}


def render(kind: str, table: MerlTable, result: FitResult | dict) -> bytes:
    """The plot called ``kind`` (one of :data:`KINDS`) as PNG bytes."""
    if kind not in RENDERERS:
        raise ValueError(f"unknown plot kind {kind!r}; choose one of {', '.join(KINDS)}")
    return RENDERERS[kind](table, _as_result(result))


def save_all(table: MerlTable, result: FitResult | dict, directory: str | os.PathLike,
             kinds=KINDS) -> list[str]:
    """Write ``<directory>/<kind>.png`` for each kind; returns the paths.

    Each file is rendered first, then written beside its place and renamed over
    it: a plot that fails to render leaves no file (not a 0-byte one), and a
    reader never sees half a PNG.
    """
    os.makedirs(directory, exist_ok=True)
    paths = []
    for kind in kinds:
        path = os.path.join(directory, f"{kind}.png")
        png = render(kind, table, result)
        fd, tmp = tempfile.mkstemp(prefix=f".{kind}.", suffix=".png.part", dir=directory)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(png)
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        paths.append(path)
    return paths
