"""How the choice of loss changes each model's errors and render PSNR on real materials.

    python -m bench.loss_bench [--materials N] [--samples 16384]

Fits each model under each loss (``brdffit.fitting.loss.LOSSES``) to N real MERL
materials (gold-metallic-paint, red-plastic, pink-felt, then an even spread; rebuilt
offline by ``data_synth.nbrdf``, cached in ``$BRDFFIT_NBRDF_CACHE`` or
``.bench-cache/nbrdf``) and reports, per model and loss, the median over materials
of every metric a result carries. No timings. Writes
bench/results/losses.{json,md}.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys

from brdffit import fit, jsonout, merl
from brdffit.fitting.loss import LOSS_METRIC
from brdffit.fitting.options import LOSSES
from data_synth import nbrdf

MODELS = ("blinn_phong", "beckmann", "ggx", "ggx2")
#: Always in: a metal, a plastic, a fabric (the materials the plots are checked on).
NAMED = ("gold-metallic-paint", "red-plastic", "pink-felt")
METRICS = ("log_rmse", "cube_root_rmse", "rmse_cos", "psnr_db")
DEFAULT_CACHE = os.environ.get("BRDFFIT_NBRDF_CACHE", os.path.join(".bench-cache", "nbrdf"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.loss_bench")
    ap.add_argument("--materials", type=int, default=12)
    ap.add_argument("--samples", type=int, default=16384)
    ap.add_argument("--cache", default=DEFAULT_CACHE)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results"))
    args = ap.parse_args(argv)
    every = sorted(nbrdf.material_names())
    step = max(1, len(every) // max(args.materials - len(NAMED), 1))
    names = list(NAMED) + [n for n in every[::step] if n not in NAMED]
    names = names[: args.materials]
    rows = []
    for name in names:
        table = merl.read(nbrdf.cached_table(name, args.cache))
        for model in MODELS:
            for loss in LOSSES:
                r = fit(table, model, loss=loss, samples=args.samples)
                rows.append({"material": name, "model": model, "loss": loss,
                             "converged": r.converged, **{m: r.error[m] for m in METRICS}})
    out = {"materials": names, "samples": args.samples, "rows": rows}
    with open(os.path.join(args.out, "losses.json"), "w") as f:
        jsonout.dump(out, f, indent=1)
    lines = ["# The loss changes the fit: medians over real materials", "",
             f"`python -m bench.loss_bench --materials {args.materials} --samples "
             f"{args.samples}`: {len(names)} MERL materials ({', '.join(names)}), each model "
             "fitted under each loss; every result reports every metric. Medians over the "
             "materials; **bold**: the best loss for that column's metric. Each loss should "
             "win its own metric; PSNR is the sphere render (`brdffit.fitting.sphere`).", "",
             "| model | loss | log_rmse | cube_root_rmse | rmse_cos (1/sr) | PSNR (dB) | "
             "not converged |", "|---|---|---|---|---|---|---|"]
    for model in MODELS:
        med = {loss: {m: statistics.median(r[m] for r in rows
                                           if r["model"] == model and r["loss"] == loss)
                      for m in METRICS} for loss in LOSSES}
        best = {m: (max if m == "psnr_db" else min)(LOSSES, key=lambda x, m=m: med[x][m])
                for m in METRICS}
        for loss in LOSSES:
            cells = []
            for m in METRICS:
                text = f"{med[loss][m]:.1f}" if m == "psnr_db" else f"{med[loss][m]:.4g}"
                cells.append(f"**{text}**" if best[m] == loss else text)
            bad = sum(not r["converged"] for r in rows
                      if r["model"] == model and r["loss"] == loss)
            lines.append(f"| {model} | {loss} (fits {LOSS_METRIC[loss]}) | "
                         + " | ".join(cells) + f" | {bad} |")
    lines.append("")
    with open(os.path.join(args.out, "losses.md"), "w") as f:
        f.write("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
