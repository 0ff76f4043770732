"""auto's rule replayed on stored rankings: try a change to the rule in seconds, on the
design half of the 100 MERL, and check it on the other half.

    python -m bench.auto_rows dump --loss log|render   # ~10 / ~20 min: one select each
    python -m bench.auto_rows replay --loss log|render  # seconds

``dump`` runs one ``select`` per MERL material over auto's default candidates and
``bench.auto_layers.LAYERED``, default options, and stores every candidate's ranking
row with bench.render_loss's independent three-light render of its fit
(``indep_psnr_db``) and the fit's parameters (to try another measure of the same fits:
a sweep of lights, another display) in the bench cache (``auto_rows_<loss>.json``; not
committed).
``replay`` re-decides each material with today's rule (``brdffit.selection.rechoose``)
among auto's defaults, among the candidates without a layer, and among them all, and
prints per half: poor verdicts, the median independent render, and how many choices
with layers are worse than those without (log_rmse above 1.001x; render more than
0.5 dB below): the figures of ``bench.auto_layers``, from rows already fitted. Edit
the rule, replay, and compare with the stored ``bench/results/auto_layers_*`` before
running that bench again.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics

import numpy as np

from bench.auto_layers import LAYERED, worse_log, worse_render
from bench.render_loss import Views, cache_dir, half, judge

#: What a row keeps of a selection's ranking row (arrays left out; the params are added
#: as lists).
KEPT = ("model", "n_params", "status", "log_rmse", "log_rmse_se", "psnr_db", "views_psnr_db",
        "verdict", "radiance_verdict", "converged", "result")


def rows_path(loss: str) -> str:
    return os.path.join(cache_dir(), f"auto_rows_{loss}.json")


def dump(loss: str) -> dict:
    from brdffit import models
    from brdffit.io import merl
    from brdffit.selection import DEFAULT_CANDIDATES, select
    from data_synth import nbrdf

    directory = os.path.join(cache_dir(), "nbrdf")
    views, out = Views(), {}
    for i, name in enumerate(nbrdf.material_names(), 1):
        path = nbrdf.cached_table(name, directory)
        with open(path, "rb") as f:
            ref = views.table_radiance(np.frombuffer(f.read()[12:], dtype="<f8").reshape(3, -1))
        sel = select(merl.read(path), (*DEFAULT_CANDIDATES, *LAYERED), loss=loss)
        rows = []
        for r in sel.ranking:
            row = {k: r.get(k) for k in KEPT}
            if r["status"] != "failed":
                fit = sel.fits[r["model"]]
                row["indep_psnr_db"] = judge(ref, views.model_radiance(
                    models.get(r["model"]), fit.params))["indep_psnr_db"]
                # the fit itself, for a replay that tries another measure of it
                row["params"] = {k: np.asarray(v).tolist() for k, v in fit.params.items()}
            rows.append(row)
        out[name] = {"chosen": sel.chosen, "rows": rows}
        print(f"[{i}] {name}: {sel.chosen}", flush=True)
    with open(rows_path(loss), "w") as f:
        json.dump(out, f, default=float)
    return out


def replay(data: dict, loss: str) -> list[str]:
    from brdffit import models
    from brdffit.selection import DEFAULT_CANDIDATES, rechoose

    lines = []
    for which in ("design", "check"):
        poor = {"ggx": 0, "auto": 0, "without layers": 0, "with layers": 0}
        log_names, db_names, indep, changed = [], [], [], 0
        for name in half(list(data), which):
            rows = data[name]["rows"]
            fitted = [r for r in rows if r["status"] != "failed"]
            bases = [r for r in fitted if not models.get(r["model"]).layers]
            picks = {"ggx": next(r for r in fitted if r["model"] == "ggx"),
                     "auto": rechoose([r for r in fitted if r["model"] in DEFAULT_CANDIDATES],
                                      loss),
                     "without layers": rechoose(bases, loss),
                     "with layers": rechoose(fitted, loss)}
            for key, row in picks.items():
                poor[key] += row.get("verdict") == "poor"
            lay, base = picks["with layers"], picks["without layers"]
            changed += lay["model"] != data[name]["chosen"]
            if worse_log(lay, base):
                log_names.append(name)
            if worse_render(lay, base):
                db_names.append(name)
            indep.append(lay["indep_psnr_db"])
        lines.append(f"{loss} loss, {which} half: poor " + ", ".join(
            f"{k} {v}" for k, v in poor.items())
            + f"; with layers: median independent render {statistics.median(indep):.2f} dB,"
            f" against without layers log_rmse > 1.001x on {len(log_names)}, render "
            f"< -0.5 dB on {len(db_names)} ({', '.join(db_names) or 'none'}); "
            f"{changed} choices differ from the dump's")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.auto_rows")
    ap.add_argument("what", choices=("dump", "replay"))
    ap.add_argument("--loss", choices=("log", "render"), default="log")
    args = ap.parse_args(argv)
    if args.what == "dump":
        data = dump(args.loss)
    else:
        if not os.path.exists(rows_path(args.loss)):
            ap.error(f"no stored rows at {rows_path(args.loss)}: run "
                     f"`python -m bench.auto_rows dump --loss {args.loss}` first")
        with open(rows_path(args.loss)) as f:
            data = json.load(f)
    print("\n".join(replay(data, args.loss)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
