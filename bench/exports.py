"""Exports on real materials: what the target models cost or gain, and what survives
the trip to each renderer, measured with the renderers' own tools.

    python -m bench.exports [--materials a,b]

Per material (tables rebuilt from the shipped neural BRDFs, ``data_synth.nbrdf``,
cached in ``$BRDFFIT_BENCH_CACHE``, default ``.bench-cache/``), default fits of

- ``ggx`` (grey Schlick f0, the base model), ``ggx2``, and the two target models
  ``rough_conductor`` (Mitsuba's conductor, coloured complex IOR) and ``gltf_pbr``;
  each fit's full-table ``log_rmse`` and its sphere-render PSNR against the table
  (``brdffit.fitting.sphere``), so the conductor's gain on metals over grey f0 is read
  off one row;
- every export of the ``ggx`` fit and of the matching target fit: ``exact`` or not,
  the reported ``log_rmse_to_fit``, the exported material's own ``log_rmse`` to the
  table, and for Mitsuba the log_rmse *measured in Mitsuba* (its BSDF eval on every
  bin) and a Mitsuba sphere render's PSNR against brdffit's render of the fit.

Writes ``bench/results/exports.{json,md}``. No timings are claimed.
"""

from __future__ import annotations

import argparse
import os
import sys
from datetime import UTC, datetime

import numpy as np

MATERIALS = ("gold-metallic-paint", "chrome", "blue-metallic-paint", "red-plastic", "pink-felt")
MODELS = ("ggx", "ggx2", "rough_conductor", "gltf_pbr", "gltf_pbr_ior")
OUT = os.path.join(os.path.dirname(__file__), "results")


def _table(name: str):
    from brdffit.io import merl
    from data_synth import nbrdf

    cache = os.environ.get("BRDFFIT_BENCH_CACHE", ".bench-cache")
    return merl.read(nbrdf.cached_table(name, os.path.join(cache, "nbrdf")))


def _mitsuba_sphere_psnr(export, model, params) -> float:
    from brdffit import models
    from brdffit.export import validate
    from brdffit.fitting import sphere as render

    se, n = 0.0, 0
    for _, light in render.LIGHTS:
        ours, lit = render.render_model(models.get(model), params, light, 128)
        exposure = 0.35 / max(float(np.median(ours[lit] @ render.LUMINANCE)), 1e-6)
        theirs = validate.mitsuba_sphere(export.material, light, 128, 64)
        d = render.tonemap(theirs, exposure)[lit] - render.tonemap(ours, exposure)[lit]
        se += float(np.sum(d * d))
        n += d.size
    return float(-10 * np.log10(se / n))


def material_row(name: str) -> dict:
    from brdffit import fit, models
    from brdffit.export import export, validate
    from brdffit.export.conversion import fit_as_table
    from brdffit.fitting.pipeline import table_error
    from brdffit.fitting.sphere import SphereReference

    table = _table(name)
    reference = SphereReference(table)
    fits, row = {}, {"material": name, "fits": {}, "exports": []}
    for model in MODELS:
        r = fit(table, model)
        fits[model] = r
        row["fits"][model] = {"log_rmse": r.log_rmse, "result": r.result,
                              "sphere_psnr_db": reference.psnr(models.get(model), r.params),
                              "params": r.params}
    for source in ("ggx", "rough_conductor", "gltf_pbr", "gltf_pbr_ior"):
        for target in ("mitsuba", "gltf", "materialx"):
            if source == "rough_conductor" and target != "mitsuba":
                continue
            if source.startswith("gltf_pbr") and target == "mitsuba":
                continue
            r = fits[source]
            e = export(r, target)
            entry = {"source": source, "target": target, **e.fidelity,
                     "exported_log_rmse_to_table": table_error(
                         table, e.fidelity["target_model"], e.target_params)["log_rmse"],
                     "warnings": e.warnings}
            if target == "mitsuba":
                entry["mitsuba_log_rmse_to_fit"] = validate.mitsuba_log_rmse(
                    e.material, fit_as_table(r).rgb)
                if e.fidelity["exact"]:
                    entry["mitsuba_sphere_psnr_db"] = _mitsuba_sphere_psnr(e, source, r.params)
            row["exports"].append(entry)
    return row


def _markdown(rows: list[dict], meta: dict) -> str:
    lines = [
        "# Exports on real materials",
        "",
        f"`python -m bench.exports` ({meta['date']}, brdffit {meta['brdffit']}, "
        f"Mitsuba {meta['mitsuba']} `{meta['mitsuba_variant']}`, MaterialX {meta['materialx']}). "
        "Default fits (16384 samples, 1 start); log_rmse on every bin of the table; sphere "
        "PSNR of brdffit's render of the fit against the table's (two lights, "
        "`brdffit.fitting.sphere`).",
        "",
        "## The target models against grey-f0 GGX",
        "",
        "| material | " + " | ".join(MODELS) + " | conductor's log_rmse below ggx's |",
        "|---|" + "---|" * (len(MODELS) + 1),
    ]
    for r in rows:
        f = r["fits"]
        cells = [f"{f[m]['log_rmse']:.4f} / {f[m]['sphere_psnr_db']:.1f} dB" for m in MODELS]
        gain = 1 - f["rough_conductor"]["log_rmse"] / f["ggx"]["log_rmse"]
        lines.append(f"| {r['material']} | " + " | ".join(cells) + f" | {gain:+.0%} |")
    lines += [
        "",
        "Cells: full-table log_rmse / sphere PSNR against the table. Last column: "
        "1 - log_rmse(rough_conductor) / log_rmse(ggx) (negative: the conductor is worse).",
        "",
        "## Fidelity of the exports",
        "",
        "| material | fit | target | exact | reported log_rmse to the fit | measured in "
        "Mitsuba | exported material vs table | Mitsuba sphere vs brdffit | largest albedo "
        "| warnings |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for e in r["exports"]:
            mi = e.get("mitsuba_log_rmse_to_fit")
            psnr = e.get("mitsuba_sphere_psnr_db")
            lines.append(
                f"| {r['material']} | {e['source']} | {e['target']} | "
                f"{'yes' if e['exact'] else 'no'} | {e['log_rmse_to_fit']:.5f} | "
                f"{'' if mi is None else f'{mi:.5f}'} | {e['exported_log_rmse_to_table']:.4f} | "
                f"{'' if psnr is None else f'{psnr:.1f} dB'} | {max(e['albedo_max']):.3f} at "
                f"{e['albedo_max_theta_deg']:g} deg | {len(e['warnings'])} |")
    lines += ["", "Warnings, per export:", ""]
    for r in rows:
        for e in r["exports"]:
            for w in e["warnings"]:
                lines.append(f"- {r['material']}, {e['source']} -> {e['target']}: {w}")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.exports")
    p.add_argument("--materials", default=",".join(MATERIALS))
    args = p.parse_args(argv)
    import MaterialX
    import mitsuba

    import brdffit
    from brdffit import jsonout
    from brdffit.export import validate

    rows = []
    for name in args.materials.split(","):
        rows.append(material_row(name))
        print(name, {m: round(f["log_rmse"], 4) for m, f in rows[-1]["fits"].items()},
              file=sys.stderr)
    meta = {"date": datetime.now(UTC).strftime("%Y-%m-%d"), "brdffit": brdffit.__version__,
            "mitsuba": mitsuba.__version__, "mitsuba_variant": validate.mitsuba().variant(),
            "materialx": MaterialX.getVersionString()}
    os.makedirs(OUT, exist_ok=True)
    with open(os.path.join(OUT, "exports.json"), "w") as f:
        f.write(jsonout.dumps({"meta": meta, "materials": rows}, indent=1))
    with open(os.path.join(OUT, "exports.md"), "w") as f:
        f.write(_markdown(rows, meta))
    return 0


if __name__ == "__main__":
    sys.exit(main())
