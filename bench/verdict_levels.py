"""Pictures at each level of the quality verdict: what 28 dB, 0.15 stops or a
CIEDE2000 of 3 look like, side by side (docs/results.md shows them).

    python -m bench.verdict_levels [--rows bench/results/render_loss_design.json]
                                   [--out docs/img/verdict_levels.png]

Reads the fits of a ``bench.render_loss`` run (each material's ``params`` under each
loss), picks materials along each of the verdict's three figures (render PSNR,
brightness in stops as displayed, colour shift in CIEDE2000), and renders each table and its fit
on the key-light sphere at the table's exposure, the fit read through the table's
bins as the verdict reads it (``brdffit.fitting.sphere``). Tables come from the
bench cache (``$BRDFFIT_BENCH_CACHE/nbrdf``), as ``bench.render_loss`` left them.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

from bench.render_loss import cache_dir

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_ROWS = os.path.join(HERE, "results", "render_loss_design.json")
DEFAULT_OUT = os.path.join(os.path.dirname(HERE), "docs", "img", "verdict_levels.png")

#: (figure, target values): for each, the fit whose figure is nearest each target.
LADDERS = (
    ("psnr_db", (36.0, 28.0, 24.0, 20.0, 14.0)),
    ("displayed_brightness_stops", (0.05, 0.15, 0.35, 0.6, 1.0)),
    ("colour_shift", (1.0, 2.0, 3.5, 6.0, 8.0)),
)

#: a ladder's figure in the pictures' captions
LABELS = {"displayed_brightness_stops": "brightness (displayed)"}


def pick(rows: list[dict]) -> list[tuple[str, dict]]:
    """(label, row) per ladder rung: the fit nearest the target, by |figure|."""
    out, used = [], set()
    for key, targets in LADDERS:
        for target in targets:
            ok = [r for r in rows if r.get(key) is not None
                  and (r["material"], r["loss"]) not in used]
            if not ok:
                continue
            r = min(ok, key=lambda r: abs(abs(r[key]) - target))
            used.add((r["material"], r["loss"]))
            out.append((f"{LABELS.get(key, key)} ~{target:g}", r))
    return out


def render_pair(table, model, params):
    """The table's and the fit's key-light spheres (tone-mapped sRGB), one exposure."""
    from brdffit.fitting import sphere

    key = sphere.LIGHTS[0][1]
    size = 160
    ref, lit = sphere.render_table(table, key, size)
    wi, _, lit_px = sphere.sphere_directions(size, key)
    wi_b, wo_b = sphere.pixel_bin_dirs(size, tuple(float(c) for c in key))
    p = {k: np.asarray(v, float) for k, v in params.items()}
    f = np.asarray(sphere.evaluate(model, p, wi_b, wo_b), np.float64)
    fit = np.zeros_like(ref)
    fit[lit_px] = sphere.radiance(f, wi[lit_px])
    ok = lit & np.all(np.isfinite(ref), axis=-1)
    exposure = sphere.table_exposure(ref[ok] @ sphere.LUMINANCE)
    background = ~sphere.sphere_disc(size, key)[2]  # off the sphere; its dark side stays black
    images = []
    for img in (np.nan_to_num(ref), fit):
        shown = sphere.tonemap(img, exposure)
        shown[background] = 0.2
        images.append(shown)
    return images


def figure(picked, model_name: str):
    from matplotlib.figure import Figure

    from brdffit import models
    from brdffit.io import merl
    from data_synth import nbrdf

    model = models.get(model_name)
    n = len(picked)
    cols = 5
    rows = -(-n // cols)
    fig = Figure(figsize=(3.2 * cols, 2.15 * rows), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    directory = os.path.join(cache_dir(), "nbrdf")
    for ax in axes.ravel():
        ax.set_axis_off()
    for ax, (label, r) in zip(axes.ravel(), picked, strict=False):
        table = merl.read(nbrdf.cached_table(r["material"], directory))
        measured, fit = render_pair(table, model, r["params"])
        ax.imshow(np.concatenate([measured, fit], axis=1), interpolation="nearest")
        ax.set_title(f"{r['material']} ({r['loss']})\n{r['psnr_db']:.1f} dB, "
                     f"{r['displayed_brightness_stops']:+.2f} stops, "
                     f"dE {r['colour_shift']:.1f}: "
                     f"{r['verdict']}", fontsize=8)
        ax.text(0.5, -0.04, f"{label}  (left: measured, right: fit)", fontsize=7,
                ha="center", va="top", transform=ax.transAxes)
    fig.suptitle(f"The quality verdict's levels: {model_name} fits to real materials, the "
                 "key-light sphere at the table's exposure", fontsize=11)
    return fig


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.verdict_levels")
    ap.add_argument("--rows", default=DEFAULT_ROWS, help="a bench.render_loss JSON file")
    ap.add_argument("--out", default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    with open(args.rows) as f:
        data = json.load(f)
    rows = [r for r in data["rows"] if r.get("displayed_brightness_stops") is not None]
    picked = pick(rows)
    fig = figure(picked, data.get("model", "ggx"))
    fig.savefig(args.out, dpi=90, facecolor="white")
    for label, r in picked:
        print(f"{label:24s} {r['material']:26s} {r['loss']:7s} {r['psnr_db']:5.1f} dB "
              f"{r['displayed_brightness_stops']:+.2f} stops dE {r['colour_shift']:5.1f} "
              f"{r['verdict']}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
