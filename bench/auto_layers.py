"""auto with layers against ggx on real materials (issue 40): poor verdicts, looks, time.

    python -m bench.auto_layers [--half design|check|all] [--loss log|render] [--limit N]

For each real material of the half (``bench.render_loss.half``), one ``select`` over
the default candidates plus the layered ones (``LAYERED``: glTF's base with its coat
and its sheen, Mitsuba's principled with and without its coat), default options, the
given loss. From that one selection's fits (nothing fitted twice):

- ``ggx``: the ggx candidate's fit, its verdict;
- ``auto``: what auto chooses among the default candidates alone (the rule re-decided
  on those rows, as ``select`` would: the tolerance rule, or the render rule under the
  render loss);
- ``auto without layers``: what it chooses among the candidates without a layer (the
  defaults and the layers' bases: gltf_pbr, principled, generalized_schlick), the
  choice that ``select``'s guard holds a layered choice to;
- ``auto with layers``: what it chooses among all of them (``select``'s own choice,
  with its guard that a layer is no worse than the choice without one);
- the best base fit and the best layered fit by log_rmse, side by side.

Each chosen fit is also judged by ``bench.render_loss``'s independent render (three
lights that neither brdffit's sphere nor the render loss uses; the table read by a
nearest-bin lookup written there from MODELS.md): ``indep_psnr_db``. Writes
bench/results/auto_layers_<half>_<loss>.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np

from bench.render_loss import Views, cache_dir, half, judge

HERE = os.path.dirname(os.path.abspath(__file__))
#: the layered candidates added to auto's defaults, with the bases they are fitted from
#: (ggx3 and ggx4 are no layers but a third and a fourth lobe over ggx2, for the metals
#: and metallic paints that read poor under the log loss: ranked as bases, left out with
#: --leave-out ggx3,ggx4)
LAYERED = ("gltf_pbr", "gltf_clearcoat", "gltf_sheen", "principled", "principled_clearcoat",
           "generalized_schlick", "ggx3", "ggx4")


def worse_log(layered: dict, base: dict) -> bool:
    """Issue 40's line on the table: the layered choice's log_rmse above 1.001x the
    base's."""
    return layered["log_rmse"] > 1.001 * base["log_rmse"]


def worse_render(layered: dict, base: dict) -> bool:
    """Issue 40's line on the look: more than 0.5 dB below the base in the independent
    render (``indep_psnr_db``)."""
    return layered["indep_psnr_db"] < base["indep_psnr_db"] - 0.5


def _rechoose(rows: list[dict], names: set[str], loss: str, tolerance: float) -> dict:
    """The row auto chooses among ``names`` alone, as ``select`` would
    (``brdffit.selection.rechoose``, on copies: the selection's rows keep their ranks)."""
    from brdffit.selection import rechoose

    return rechoose([r for r in rows if r["model"] in names], loss, tolerance)


def run(names: list[str], loss: str, layered: tuple[str, ...] = LAYERED) -> list[dict]:
    from brdffit import models
    from brdffit.fitting.options import DEFAULT_TOLERANCE
    from brdffit.io import merl
    from brdffit.selection import DEFAULT_CANDIDATES, select
    from data_synth import nbrdf

    candidates = (*DEFAULT_CANDIDATES, *layered)
    directory = os.path.join(cache_dir(), "nbrdf")
    views = Views()
    select(merl.read(nbrdf.cached_table(names[0], directory)), candidates, loss=loss)  # warm
    rows = []
    for i, name in enumerate(names):
        path = nbrdf.cached_table(name, directory)
        table = merl.read(path)
        with open(path, "rb") as f:
            raw = np.frombuffer(f.read()[12:], dtype="<f8").reshape(3, -1)
        ref = views.table_radiance(raw)
        t0 = time.perf_counter()
        sel = select(table, candidates, loss=loss)
        took = time.perf_counter() - t0
        ranking = {r["model"]: r for r in sel.ranking if r["status"] != "failed"}

        def entry(model: str) -> dict:
            r = ranking[model]
            fit = sel.fits[model]
            return {"model": model, "verdict": r["verdict"], "log_rmse": r["log_rmse"],
                    "psnr_db": r["psnr_db"], "time_s": fit.time_s,
                    **judge(ref, views.model_radiance(models.get(model), fit.params))}

        plain = _rechoose(sel.ranking, set(DEFAULT_CANDIDATES), loss, DEFAULT_TOLERANCE)
        layered = [m for m in ranking if models.get(m).layers]
        bases = [m for m in ranking if m not in layered]
        without = _rechoose(sel.ranking, set(bases), loss, DEFAULT_TOLERANCE)
        row = {"material": name, "select_s": took,
               "ggx": entry("ggx"), "auto": entry(plain["model"]),
               "auto_bases": entry(without["model"]),
               "auto_layers": entry(sel.chosen),
               "best_base": entry(min(bases, key=lambda m: ranking[m]["log_rmse"])),
               "best_layered": entry(min(layered, key=lambda m: ranking[m]["log_rmse"]))}
        rows.append(row)
        print(f"[{i + 1}/{len(names)}] {name}: ggx {row['ggx']['verdict']}, auto "
              f"{row['auto']['model']} {row['auto']['verdict']}, with layers "
              f"{sel.chosen} {row['auto_layers']['verdict']} ({took:.1f} s)", flush=True)
    return rows


def report(rows: list[dict], which: str, loss: str, layered: tuple[str, ...] = LAYERED,
           command: str = "") -> str:
    def poor(key):
        return sum(r[key]["verdict"] == "poor" for r in rows)

    def med(key, field):
        return statistics.median(r[key][field] for r in rows)

    lines = [f"# auto with layers, {which} half ({len(rows)} materials), {loss} loss", "",
             f"Generated by `python -m bench.auto_layers {command}`: one "
             "`select` per material over auto's default candidates and "
             f"{', '.join(layered)}, default options. `indep` is bench.render_loss's "
             "independent three-light render.", "",
             "| fit | poor | median indep PSNR dB | median log_rmse |", "|---|---|---|---|"]
    for key, label in (("ggx", "ggx"), ("auto", "auto (default candidates)"),
                       ("auto_bases", "auto without layers (defaults and the layers' bases)"),
                       ("auto_layers", "auto with layers"), ("best_base", "best base fit"),
                       ("best_layered", "best layered fit")):
        lines.append(f"| {label} | {poor(key)} | {med(key, 'indep_psnr_db'):.2f} | "
                     f"{med(key, 'log_rmse'):.4g} |")
    def worse(key):
        log = [r["material"] for r in rows if worse_log(r["auto_layers"], r[key])]
        db = [r["material"] for r in rows if worse_render(r["auto_layers"], r[key])]
        return (f"log_rmse above 1.001x on {len(log)} ({', '.join(log) or 'none'}); "
                f"independent render more than 0.5 dB worse on {len(db)} "
                f"({', '.join(db) or 'none'})")

    chosen = {}
    for r in rows:
        chosen[r["auto_layers"]["model"]] = chosen.get(r["auto_layers"]["model"], 0) + 1
    lines += ["", f"auto with layers against auto without layers: {worse('auto_bases')}.", "",
              f"auto with layers against auto (default candidates): {worse('auto')}.", "",
              "Chosen with layers: " + ", ".join(f"{m} {n}" for m, n in
                                                 sorted(chosen.items(), key=lambda x: -x[1]))
              + f". Median select time {statistics.median(r['select_s'] for r in rows):.1f} s.",
              "", "| material | ggx | auto | auto with layers | indep dB ggx / auto / layers |",
              "|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['material']} | {r['ggx']['verdict']} | {r['auto']['model']} "
            f"{r['auto']['verdict']} | {r['auto_layers']['model']} "
            f"{r['auto_layers']['verdict']} | {r['ggx']['indep_psnr_db']:.1f} / "
            f"{r['auto']['indep_psnr_db']:.1f} / {r['auto_layers']['indep_psnr_db']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.auto_layers")
    ap.add_argument("--half", choices=("design", "check", "all"), default="design")
    ap.add_argument("--loss", choices=("log", "render"), default="log")
    ap.add_argument("--limit", type=int, default=None, help="first N materials only")
    ap.add_argument("--leave-out", default="",
                    help="comma-separated layered candidates left out (their effect: the "
                         "same run without them), written to ..._without_NAME")
    args = ap.parse_args(argv)
    from data_synth import nbrdf

    left = tuple(n for n in args.leave_out.split(",") if n)
    layered = tuple(m for m in LAYERED if m not in left)
    names = half(nbrdf.material_names(), args.half)[: args.limit]
    rows = run(names, args.loss, layered)
    out = os.path.join(HERE, "results", f"auto_layers_{args.half}_{args.loss}"
                       + "".join(f"_without_{n}" for n in left))
    command = f"--half {args.half} --loss {args.loss}" + (
        f" --leave-out {args.leave_out}" if left else "")
    with open(out + ".json", "w") as f:
        json.dump(rows, f, indent=1)
    with open(out + ".md", "w") as f:
        f.write(report(rows, args.half, args.loss, layered, command))
    print(f"wrote {out}.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
