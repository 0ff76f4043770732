"""Does a sample list's held-out verdict say how its fit really looks?

    python -m bench.sample_verdicts [--half design|check|all] [--model ggx] [-n 4000]

For each real material of the half (``bench.render_loss.half``: sorted names, even
positions design, odd ones check), sparse sample lists (``data_synth.sparse``: the
``cornell`` and ``uniform`` layouts, 2% noise) are fitted (``brdffit.fitting.samples``:
the verdict from held-out samples), and each fit's true verdict is its sphere against
the material's dense MERL table (``data_synth.nbrdf``), which it never saw. Reported:
how often the two verdicts agree, the confusion counts, and the PSNRs side by side
(the dense table's own fit beside, for reference). Writes
bench/results/sample_verdicts_<half>.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from bench.render_loss import half

HERE = os.path.dirname(os.path.abspath(__file__))
LAYOUTS = ("cornell", "uniform")
VERDICTS = ("good", "visible", "poor")


def run(names: list[str], model: str, n: int, noise: float) -> list[dict]:
    from brdffit import models
    from brdffit.fitting.pipeline import fit
    from brdffit.fitting.quality import judged_brightness, verdict
    from brdffit.fitting.sphere import SphereReference
    from data_synth import nbrdf
    from data_synth.sparse import sample_material

    m = models.get(model)
    rows = []
    for i, name in enumerate(names):
        t0 = time.perf_counter()
        table = nbrdf.make_table(name)
        reference = SphereReference(table)
        table_fit = fit(table, model)
        row = {"material": name, "table": {"verdict": table_fit.quality["verdict"],
                                           "psnr_db": table_fit.error["psnr_db"],
                                           "log_rmse": table_fit.error["log_rmse"]}}
        for layout in LAYOUTS:
            meas = sample_material(name, layout, n, noise=noise, seed=i)
            r = fit(meas, model)
            # how the samples' fit really looks: its sphere against the dense table's
            psnr, colour = reference.psnr_and_colour(m, r.params)
            key = colour["key"]
            true, _ = verdict(psnr, judged_brightness(key), key["colour_shift"])
            row[layout] = {"verdict": r.quality["verdict"], "psnr_db": r.error["psnr_db"],
                           "true_verdict": true, "true_psnr_db": psnr,
                           "basis": r.quality["basis"],
                           "log_rmse": r.error["log_rmse"],
                           "held_out_log_rmse": r.error.get("held_out_log_rmse"),
                           "peak_seen": r.input["coverage"]["peak_seen"],
                           "fit_time_s": r.time_s}
        rows.append(row)
        print(f"[{i + 1}/{len(names)}] {name}: table fit {row['table']['verdict']} "
              f"{row['table']['psnr_db']:.1f} dB; "
              + "; ".join(f"{lay} held out {row[lay]['verdict']} {row[lay]['psnr_db']:.1f} dB, "
                          f"true {row[lay]['true_verdict']} {row[lay]['true_psnr_db']:.1f} dB"
                          for lay in LAYOUTS)
              + f" ({time.perf_counter() - t0:.1f} s)", flush=True)
    return rows


def report(rows: list[dict], which: str, model: str, n: int, noise: float) -> str:
    lines = [f"# Held-out verdicts of sample lists against the truth ({which} half)", "",
             f"`python -m bench.sample_verdicts --half {which} --model {model} -n {n}`: "
             f"{len(rows)} real materials, each sampled ({n} samples, {noise:.0%} noise) in "
             f"each layout and fitted with {model}. The held-out verdict (what the fit "
             "reports, from held-out samples) against the true one: the same fit's sphere "
             "verdict against the material's dense table, which the fit never saw. The "
             "table's own fit's verdict is in the per-material table for reference.", ""]
    for layout in LAYOUTS:
        pairs = [(r[layout]["true_verdict"], r[layout]["verdict"]) for r in rows]
        agree = sum(t == h for t, h in pairs)
        off = [abs(VERDICTS.index(t) - VERDICTS.index(h)) for t, h in pairs]
        d = np.array([r[layout]["psnr_db"] - r[layout]["true_psnr_db"] for r in rows
                      if r[layout]["psnr_db"] is not None])
        better = sum(VERDICTS.index(h) < VERDICTS.index(t) for t, h in pairs)
        lines += [f"## {layout}", "",
                  f"Same verdict: {agree} of {len(rows)}; one level apart: "
                  f"{sum(o == 1 for o in off)}; two: {sum(o == 2 for o in off)}; kinder than "
                  f"the truth: {better}. Held-out PSNR minus true PSNR: median "
                  f"{np.median(d):+.1f} dB, middle half {np.percentile(d, 25):+.1f} to "
                  f"{np.percentile(d, 75):+.1f} dB.",
                  "", "| true \\ held out | good | visible | poor |", "|---|---|---|---|"]
        for v in VERDICTS:
            counts = [sum(t == v and h == w for t, h in pairs) for w in VERDICTS]
            lines.append(f"| {v} | " + " | ".join(map(str, counts)) + " |")
        lines.append("")
    lines += ["## Per material", "",
              "held-out verdict and PSNR / true verdict and PSNR of each layout's fit",
              "", "| material | table's own fit | " + " | ".join(LAYOUTS) + " |",
              "|---|---|" + "---|" * len(LAYOUTS)]
    for r in rows:
        lines.append(f"| {r['material']} | {r['table']['verdict']} {r['table']['psnr_db']:.1f} | "
                     + " | ".join(f"{r[lay]['verdict']} {r[lay]['psnr_db']:.1f} / "
                                  f"{r[lay]['true_verdict']} {r[lay]['true_psnr_db']:.1f}"
                                  + ("" if r[lay]["peak_seen"] is not False else " (peak unseen)")
                                  for lay in LAYOUTS) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from data_synth import nbrdf

    ap = argparse.ArgumentParser(prog="python -m bench.sample_verdicts", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--half", choices=("design", "check", "all"), default="design")
    ap.add_argument("--model", default="ggx")
    ap.add_argument("-n", type=int, default=4000)
    ap.add_argument("--noise", type=float, default=0.02)
    ap.add_argument("--limit", type=int, help="the first LIMIT materials of the half")
    args = ap.parse_args(argv)
    names = half(nbrdf.material_names(), args.half)[: args.limit]
    rows = run(names, args.model, args.n, args.noise)
    out = os.path.join(HERE, "results", f"sample_verdicts_{args.half}")
    with open(out + ".json", "w") as f:
        json.dump(rows, f, indent=1)
    with open(out + ".md", "w") as f:
        f.write(report(rows, args.half, args.model, args.n, args.noise))
    print(f"wrote {out}.md and {out}.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
