"""Every sample of a sample list's fit, fitted against measured (``samples.png``).

A sample list fills a few of the MERL grid's bins: its slices, spheres and polar plot
(:mod:`brdffit.view.plots`, drawn from the table the samples bin into) show little of
it, and say so. This plot shows each sample: on the left the fit's value at the
sample's own directions against the measured one, per channel, on log axes with the
line of a perfect fit and a factor of 2 either side; on the right how far off each
sample is (log2 of fit over measured, luminance) against its theta_h, coloured by its
theta_d: where along the highlight, and at which angle between light and view, the
fit misses.
"""

from __future__ import annotations

import os
import textwrap

import numpy as np
from matplotlib.figure import Figure

from brdffit.fitting.result import FitResult
from brdffit.io.angles import dirs_to_half_diff
from brdffit.io.measurements import Measurements
from brdffit.view.drawing import (
    CHANNELS,
    LUMINANCE,
    as_result,
    evaluate,
    png_bytes,
    source_name,
    sqrt_degree_axis,
)

#: Samples drawn at most (a random subset beyond it, said in the title): a scatter of
#: millions of dots is a solid blot, and slow to draw.
MAX_DRAWN = 20_000
#: The ratio panel's range, in stops either way (samples beyond it sit at its edge).
RATIO_STOPS = 4.0


def samples(measured: Measurements, result: FitResult | dict) -> bytes:
    """The plot (PNG bytes) of ``result``, a fit of ``measured``, at every sample."""
    r = as_result(result)
    fig = Figure(figsize=(17.5, 5.6), layout="constrained")
    shown, not_drawn = draw(fig, measured, r)
    fig.suptitle(_title(measured, r, shown, not_drawn), fontsize=10)
    return png_bytes(fig)


def draw(fig, measured: Measurements, r: FitResult) -> tuple[int, int]:
    """The three panels into ``fig`` (a figure or a subfigure: the one-page report of a
    sample list draws them in place of its spheres); returns how many samples are drawn
    and how many of those have a value <= 0 or are below the horizon."""
    fitted = evaluate(r, measured.wi, measured.wo)  # NaN below the horizon
    shown = np.arange(measured.n)
    if measured.n > MAX_DRAWN:
        shown = np.sort(np.random.default_rng(0).choice(measured.n, MAX_DRAWN, replace=False))
    meas, fit = measured.rgb[shown], fitted[shown]
    theta_h, theta_d, _ = dirs_to_half_diff(measured.wi[shown], measured.wo[shown])
    drawable = (meas > 0) & np.isfinite(fit) & (fit > 0)

    ax, right, hue = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1, 1.35, 1.1]})
    # few samples drawn large, many small and faint: each still seen, the crowd's density too
    size, alpha = (14, 0.6) if len(shown) <= 2000 else (5, 0.3)
    for c, (label, colour) in enumerate(CHANNELS):
        ok = drawable[:, c]
        ax.scatter(meas[ok, c], fit[ok, c], s=size, alpha=alpha, color=colour, lw=0,
                   label=label)
    both = np.concatenate([meas[drawable], fit[drawable]])
    if both.size:
        lo, hi = float(both.min()) / 1.5, float(both.max()) * 1.5
        line = np.array([lo, hi])
        ax.plot(line, line, color="black", lw=1, label="fit = measured")
        for k in (0.5, 2.0):
            ax.plot(line, k * line, color="grey", lw=0.8, ls="--")
        ax.set_xlim(lo, hi)
        ax.set_ylim(lo, hi)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("measured f_r (1/sr)")
    ax.set_ylabel("fitted f_r at the sample's directions (1/sr)")
    ax.set_title("each sample and channel (dashed: a factor of 2)", fontsize=9)
    ax.legend(loc="upper left", fontsize=8, markerscale=2)
    ax.grid(True, which="major", alpha=0.3)

    lum_meas, lum_fit = meas @ LUMINANCE, fit @ LUMINANCE
    ok = ok_full(lum_meas, lum_fit)
    stops = np.clip(np.log2(lum_fit[ok] / lum_meas[ok]), -RATIO_STOPS, RATIO_STOPS)
    dots = right.scatter(np.degrees(theta_h[ok]), stops, c=np.degrees(theta_d[ok]), s=size,
                         cmap="viridis", vmin=0, vmax=90, lw=0, alpha=max(alpha, 0.5))
    right.axhline(0.0, color="black", lw=1)
    for k in (-1.0, 1.0):
        right.axhline(k, color="grey", lw=0.8, ls="--")
    right.set_ylim(-RATIO_STOPS - 0.2, RATIO_STOPS + 0.2)
    sqrt_degree_axis(right, "x")
    right.set_xlabel("theta_h (degrees, sqrt scale)")
    right.set_ylabel("log2(fit / measured), luminance (+1: fit 2x brighter)")
    right.set_title(f"where the fit is off (clipped at {RATIO_STOPS:g} stops)", fontsize=9)
    fig.colorbar(dots, ax=right, label="theta_d (degrees)")
    # each channel against the luminance: a colour error (a verdict's CIEDE2000) shows
    # here, where the luminance panel beside it read "within 0.6 stops" (a review)
    for c, (label, colour) in enumerate(CHANNELS):
        both_ok = drawable[:, c] & ok_full(lum_meas, lum_fit)
        rel = (np.log2(fit[both_ok, c] / meas[both_ok, c])
               - np.log2(lum_fit[both_ok] / lum_meas[both_ok]))
        hue.scatter(np.degrees(theta_h[both_ok]), np.clip(rel, -RATIO_STOPS, RATIO_STOPS),
                    s=size, color=colour, lw=0, alpha=alpha, label=label)
    hue.axhline(0.0, color="black", lw=1)
    hue.set_ylim(-RATIO_STOPS - 0.2, RATIO_STOPS + 0.2)
    sqrt_degree_axis(hue, "x")
    hue.set_xlabel("theta_h (degrees, sqrt scale)")
    hue.set_ylabel("channel's log2(fit / measured) less the luminance's")
    hue.set_title("colour: each channel's error beyond the brightness's", fontsize=9)
    hue.legend(loc="upper right", fontsize=8, markerscale=2)
    return len(shown), int(np.count_nonzero(~drawable.all(1)))


def ok_full(lum_meas: np.ndarray, lum_fit: np.ndarray) -> np.ndarray:
    """Samples whose measured and fitted luminance are both drawable (> 0, finite)."""
    return (lum_meas > 0) & np.isfinite(lum_fit) & (lum_fit > 0)


def _title(measured: Measurements, r: FitResult, n_shown: int, not_drawn: int) -> str:
    name = source_name(measured.source)
    e = r.error
    held = e.get("held_out_log_rmse")
    inside = e.get("sample_log_rmse", e.get("log_rmse"))
    figures = ", ".join(x for x in (
        None if held is None else f"held-out log_rmse {held:.3g}",
        None if inside is None else f"in-sample {inside:.3g}") if x)
    shown = (f"{measured.n:,} samples" if n_shown == measured.n
             else f"{n_shown:,} of {measured.n:,} samples (a random subset)")
    lost = (f"; {not_drawn:,} with a value <= 0 or below the horizon are not on the log axes"
            if not_drawn else "")
    psnr = e.get("psnr_db")
    verdict = (r.quality or {}).get("verdict")
    look = "; ".join(x for x in (
        None if psnr is None else f"held-out PSNR {psnr:.1f} dB",
        None if verdict is None else f"looks {verdict}") if x)
    line = (f"{name}: {r.model} fit at each of its samples' own directions; {shown}"
            f"{'; ' + figures if figures else ''}{'; ' + look if look else ''}{lost}")
    return "\n".join(textwrap.wrap(line, 120))


#: The file :func:`save` writes beside the other plots.
FILE = "samples.png"


def save(measured: Measurements, result: FitResult | dict,
         directory: str | os.PathLike) -> str:
    """Write ``<directory>/samples.png`` (rendered first, then renamed over its place,
    as every plot is: ``brdffit.io.atomic``); returns its path."""
    from brdffit.io import atomic

    os.makedirs(directory, exist_ok=True)
    path = os.path.join(directory, FILE)
    atomic.write_bytes(path, samples(measured, result), prefix=".samples.")
    return path
