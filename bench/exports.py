"""Exports and physically bounded fits on the 100 real materials, measured with the
renderers' own tools.

    python -m bench.exports [--materials a,b] [--out DIR]

Per material (tables rebuilt from the shipped neural BRDFs, ``data_synth.nbrdf``,
cached in ``$BRDFFIT_BENCH_CACHE``, default ``.bench-cache/``):

- default fits of ``ggx`` (grey Schlick f0), ``rough_conductor`` (Mitsuba's conductor,
  coloured complex IOR) and ``gltf_pbr`` (glTF's BRDF), each unconstrained and
  physically bounded (``brdffit.fitting.physical.bound`` of that same fit: what
  ``fit(..., physical=True)`` returns): full-table ``log_rmse``, sphere PSNR against
  the table, the bounded fit's cost and the bounds it met;
- the exports: ``ggx -> mitsuba`` and ``ggx -> gltf`` (approximated: the target's model
  refitted to the fit; ``ggx -> materialx`` is the same refit as ``ggx -> gltf`` and is
  not repeated), ``rough_conductor -> mitsuba``, ``gltf_pbr -> gltf`` and
  ``gltf_pbr -> materialx`` (exact): the fidelity the export reports, the exported
  material's ``log_rmse`` to the table, and

  - Mitsuba 3: the ``log_rmse`` to the fit *measured in Mitsuba* (its ``BSDF.eval`` on
    every bin above the horizon, ``brdffit.export.validate.mitsuba_log_rmse``); for
    the exact export the largest relative difference between Mitsuba's values and
    brdffit's model on 4,096 sampled bins; a Mitsuba sphere render (``direct``
    integrator, 128 px, 64 spp, two lights) against brdffit's render of the fit, PSNR;
  - glTF: the Khronos validator (``--gltf-validator``, the npm package's folder;
    skipped where absent or without Node.js); MaterialX: its own validation.

Writes ``bench/results/exports.{json,md}`` (medians, worst cases, one row per material)
and logs each material's progress on stderr. The whole run takes ~15-25 min on a
2-core machine (the ``rough_conductor`` fits are most of it).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback
from datetime import UTC, datetime

import numpy as np

MODELS = ("ggx", "rough_conductor", "gltf_pbr", "standard_surface")
#: The fits whose physically bounded twin is measured too.
BOUNDED = ("ggx", "rough_conductor", "gltf_pbr")
#: (source fit, target, target model or None for the target's default): the exports
#: measured for every material, grouped by renderer.
EXPORTS = (("ggx", "mitsuba", None), ("rough_conductor", "mitsuba", None),
           ("ggx", "gltf", None), ("gltf_pbr", "gltf", None),
           ("ggx", "materialx", None), ("standard_surface", "materialx", None),
           ("gltf_pbr", "materialx", "gltf_pbr"))
#: A metallic strictly between these is fractional: there glTF's definition and its
#: implementation pseudocode differ.
FRACTIONAL = (0.01, 0.99)
#: Bare metals of the MERL set, and its metallic paints (metal flakes in a binder): the
#: materials the conductor model is for.
METALS = ("alum-bronze", "aluminium", "black-oxidized-steel", "brass", "chrome",
          "chrome-steel", "grease-covered-steel", "hematite", "nickel", "ss440", "steel",
          "tungsten-carbide", "two-layer-gold", "two-layer-silver")
METALLIC_PAINTS = ("blue-metallic-paint", "blue-metallic-paint2", "gold-metallic-paint",
                   "gold-metallic-paint2", "gold-metallic-paint3", "gold-paint",
                   "green-metallic-paint", "green-metallic-paint2", "red-metallic-paint",
                   "silver-metallic-paint", "silver-metallic-paint2", "silver-paint")
#: Samples per pixel of the RGB-vs-spectral spheres of near-mirror lobes (alpha below).
NEAR_MIRROR_SPP, NEAR_MIRROR_ALPHA = 1024, 0.02
#: Measured bins MaterialX's own GLSL evaluates per export (a fixed random subset).
MATERIALX_BINS = 50000
#: Sampled bins for the exact export's value-by-value comparison with Mitsuba.
EVAL_SAMPLES = 4096
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "bench", "results")
DEFAULT_VALIDATOR = os.path.join(ROOT, ".tools", "gltf-validator", "node_modules",
                                 "gltf-validator")


def _table(name: str):
    from brdffit.io import merl
    from data_synth import nbrdf

    cache = os.environ.get("BRDFFIT_BENCH_CACHE", os.path.join(ROOT, ".bench-cache"))
    return merl.read(nbrdf.cached_table(name, os.path.join(cache, "nbrdf")))


def _mitsuba_sphere_psnr(material: dict, model: str, params: dict,
                         supersample: int = 1) -> float:
    """Mitsuba's render of ``material`` against brdffit's render of ``model`` with
    ``params``, both lights of ``brdffit.fitting.sphere``, exposed and tone-mapped alike.

    ``supersample`` > 1: brdffit's render at that many times the resolution, averaged
    over each pixel as Mitsuba's box filter integrates it, and compared on the pixels
    wholly inside the sphere; 1: brdffit's render at the pixel centres, on every lit
    pixel (as tests/test_export_tools.py), which on a near-mirror highlight differs
    from a pixel's average by more than Mitsuba's noise."""
    from brdffit import models
    from brdffit.export import validate
    from brdffit.fitting import sphere as render

    size = 128
    se, n = 0.0, 0
    for _, light in render.LIGHTS:
        ours, lit = render.render_model(models.get(model), params, light, size)
        exposure = 0.35 / max(float(np.median(ours[lit] @ render.LUMINANCE)), 1e-6)
        if supersample > 1:
            fine, fine_lit = render.render_model(models.get(model), params, light,
                                                 size * supersample)
            shape = (size, supersample, size, supersample)
            ours = fine.reshape(*shape, 3).mean(axis=(1, 3))
            lit = fine_lit.reshape(shape).all(axis=(1, 3))
        theirs = validate.mitsuba_sphere(material, light, size, 64)
        d = render.tonemap(theirs, exposure)[lit] - render.tonemap(ours, exposure)[lit]
        se += float(np.sum(d * d))
        n += d.size
    return float(-10 * np.log10(max(se / n, 1e-12)))


def _eval_difference(material: dict, model: str, params: dict) -> dict:
    """Largest relative difference between Mitsuba's BSDF values of ``material`` and
    brdffit's ``model``, where there is a value to compare (above 1e-6 of the largest,
    as tests/test_export_tools.py): on EVAL_SAMPLES direction pairs drawn uniformly over
    the hemisphere (``random``), and on EVAL_SAMPLES bin centres of the MERL grid
    (``bins``; ``bins_theta_d_below_85``: those with theta_d < 85 degrees)."""
    import jax.numpy as jnp

    from brdffit import models, runtime
    from brdffit.export import validate
    from brdffit.io.grid import bin_grid

    rng = np.random.default_rng(0)
    v = rng.normal(size=(2, EVAL_SAMPLES, 3))
    v[..., 2] = np.abs(v[..., 2]) + 1e-3  # strictly above the horizon
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    g = bin_grid()
    idx = rng.choice(np.flatnonzero(g.above_horizon), EVAL_SAMPLES, replace=False)
    m = models.get(model)
    out = {}
    for key, wi, wo, keep in (
            ("random", v[0], v[1], np.ones(EVAL_SAMPLES, bool)),
            ("bins", g.wi[idx], g.wo[idx], np.ones(EVAL_SAMPLES, bool)),
            ("bins_theta_d_below_85", g.wi[idx], g.wo[idx], g.theta_d[idx] < np.radians(85))):
        theirs = validate.mitsuba_eval(material, wi, wo)
        with runtime.float64():
            p = {k: jnp.asarray(x) for k, x in m.check_params(params).items()}
            ours = np.asarray(m(p, jnp.asarray(wi), jnp.asarray(wo)))
        ok = (ours > 1e-6 * ours.max()) & keep[:, None]
        out[key] = float(np.max(np.abs(theirs[ok] - ours[ok]) / ours[ok]))
    return out


def _fit_row(r, bounded) -> dict:
    p = bounded.physical
    return {
        "log_rmse": r.error["log_rmse"], "psnr_db": r.error["psnr_db"], "result": r.result,
        "time_s": r.time_s, "params": r.params,
        "bounded": {
            "log_rmse": bounded.error["log_rmse"], "psnr_db": bounded.error["psnr_db"],
            "result": bounded.result, "relative_cost": p["relative_cost"],
            "albedo_max_before": max(p["albedo_max_before"]),
            "albedo_max_after": max(p["albedo_max_after"]),
            "albedo_max_theta_deg": p["albedo_max_before_theta_deg"],
            "active": p["active"], "scale": p["scale"], "params": bounded.params,
            "time_s": bounded.time_s - r.time_s,
        },
    }


def _measured_bins(table):
    """Every measured bin above the horizon: its index, the table's values (n, 3), and
    the direction pairs, cos_i and solid-angle weights the loss uses."""
    from brdffit.io.grid import bin_grid

    g = bin_grid()
    idx = np.flatnonzero(table.mask.ravel() & g.above_horizon)
    return (idx, table.rgb.reshape(3, -1)[:, idx].T, g.wi[idx], g.wo[idx], g.cos_i[idx],
            g.weight[idx])


def _independent_to_table(e, table) -> dict:
    """The exported file's log_rmse to the table, evaluated without brdffit's models:
    by Mitsuba itself (``BSDF.eval``), by glTF's spec written out in numpy (its
    definition and its implementation pseudocode), by MaterialX's own shader code."""
    from brdffit.export import validate

    _, ref, wi, wo, cos_i, w = _measured_bins(table)
    out = {}
    if e.target == "mitsuba":
        out["independent"] = validate.log_rmse(validate.mitsuba_eval(e.material, wi, wo), ref,
                                               cos_i, w)
    elif e.target == "gltf":
        out["independent"] = validate.log_rmse(
            validate.gltf_spec_eval(e.target_params, wi, wo), ref, cos_i, w)
        out["pseudocode"] = validate.log_rmse(
            validate.gltf_spec_eval(e.target_params, wi, wo, pseudocode=True), ref, cos_i, w)
    elif e.target == "materialx" and e.fidelity["renderer_model"] is not None:
        # MaterialX's GLSL draws one light direction at a time (~5 us a draw here), so
        # on a fixed random subset of the bins; brdffit's model on the same subset
        # separates the renderer's agreement from the subset's sampling
        import jax.numpy as jnp

        from brdffit import models, runtime

        pick = np.random.default_rng(0).choice(len(w), min(MATERIALX_BINS, len(w)),
                                               replace=False)
        theirs = validate.materialx_eval(e.material, wi[pick], wo[pick])
        m = models.get(e.fidelity["renderer_model"])
        with runtime.float64():
            p = {k: jnp.asarray(v) for k, v in m.check_params(e.target_params).items()}
            ours = np.asarray(m(p, jnp.asarray(wi[pick]), jnp.asarray(wo[pick])))
        args = (ref[pick], cos_i[pick], w[pick])
        out["independent"] = validate.log_rmse(theirs, *args)
        out["model_on_subset"] = validate.log_rmse(ours, *args)
        ok = ours > 1e-6 * ours.max()
        out["materialx_max_rel_diff"] = float(np.max(np.abs(theirs[ok] - ours[ok]) / ours[ok]))
    return out


def _spectral_agreement(params: dict) -> dict:
    """The exported conductor's key-light sphere in Mitsuba's ``scalar_rgb`` (NAME.xml)
    and ``scalar_spectral`` (NAME_spectral.xml): mean colours and their relative
    difference per channel (``bench.mitsuba_spectral``)."""
    from bench.mitsuba_spectral import mean_colours
    from brdffit.export.mitsuba import SpectralExportError

    # a near-mirror highlight is smaller than a pixel: at 64 samples per pixel the mean
    # of scalar_rgb against itself with another seed differs by ~12% (chrome-steel)
    spp = NEAR_MIRROR_SPP if params["alpha"] < NEAR_MIRROR_ALPHA else 64
    try:
        rgb, spectral = mean_colours(params, spp=spp)
    except SpectralExportError as e:
        return {"refused": str(e), "relative_difference": [float("inf")] * 3}
    return {"rgb": rgb.tolist(), "spectral": spectral.tolist(),
            "relative_difference": (spectral / np.maximum(rgb, 1e-12) - 1).tolist(), "spp": spp}


def material_row(name: str, validator: str | None) -> dict:
    from brdffit import fit
    from brdffit.export import export, validate
    from brdffit.export.conversion import fit_as_table
    from brdffit.fitting.physical import bound
    from brdffit.fitting.problem import table_error

    table = _table(name)
    fits, row = {}, {"material": name, "fits": {}, "exports": []}
    for model in MODELS:
        r = fit(table, model)
        fits[model] = r
        row["fits"][model] = (_fit_row(r, bound(table, r)) if model in BOUNDED else
                              {"log_rmse": r.error["log_rmse"], "psnr_db": r.error["psnr_db"],
                               "result": r.result, "time_s": r.time_s, "params": r.params})
    for source, target, target_model in EXPORTS:
        r = fits[source]
        e = export(r, target, table=table, target_model=target_model)
        entry = {"source": source, "target": target, "requested": target_model, **e.fidelity,
                 "fit_log_rmse_to_table": table_error(table, source, r.params)["log_rmse"],
                 "target_params": e.target_params,
                 "warnings": e.warnings, **_independent_to_table(e, table)}
        if target == "mitsuba":
            entry["mitsuba_log_rmse_to_fit"] = validate.mitsuba_log_rmse(
                e.material, fit_as_table(r).rgb)
            entry["spectral_colour"] = _spectral_agreement(e.target_params)
            if e.fidelity["exact"]:
                entry["mitsuba_sphere_psnr_db_same_material"] = _mitsuba_sphere_psnr(
                    e.material, e.fidelity["target_model"], e.target_params, supersample=4)
                entry["mitsuba_eval_max_rel_diff"] = _eval_difference(e.material, source,
                                                                      r.params)
        elif target == "gltf" and validator:
            issues = validate.gltf_validate(e.material, validator)["issues"]
            entry["gltf_validator"] = {"errors": issues["numErrors"],
                                       "warnings": issues["numWarnings"]}
        elif target == "materialx":
            entry["materialx_valid"] = validate.materialx_validate(e.material)[0]
        row["exports"].append(entry)
    return row


# -- the summary -----------------------------------------------------------------------


def _stats(values) -> dict:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    if not v.size:
        return {"n": 0}
    return {"n": int(v.size), "median": float(np.median(v)), "min": float(v.min()),
            "max": float(v.max())}


def summarise(rows: list[dict]) -> dict:
    ok = [r for r in rows if "error" not in r]
    out = {"materials": len(rows), "failed": [r["material"] for r in rows if "error" in r],
           "fits": {}, "exports": {}, "conductor_gain": {}}
    for m in BOUNDED:
        f = [r["fits"][m] for r in ok]
        b = [x["bounded"] for x in f]
        costs = [x["relative_cost"] for x in b]
        out["fits"][m] = {
            "log_rmse": _stats(x["log_rmse"] for x in f),
            "bounded_log_rmse": _stats(x["log_rmse"] for x in b),
            "relative_cost": _stats(costs),
            "bounded_materials": sum(1 for c in costs if c),
            "relative_cost_where_bounded": _stats(c for c in costs if c),
            "converged": sum(x["result"] == "successful" for x in f),
            "bounded_converged": sum(x["result"] == "successful" for x in b),
            "albedo_max_before": _stats(x["albedo_max_before"] for x in b),
            "albedo_max_after": _stats(x["albedo_max_after"] for x in b),
            "clamped": sum(x["scale"] < 1 for x in b),
            "active": {kind: sum(any(a.startswith(kind) for a in x["active"]) for x in b)
                       for kind in ("range", "energy", "clamp")},
            "bound_time_s": _stats(x["time_s"] for x in b if x["relative_cost"]),
        }
    for source, target, target_model in EXPORTS:
        e = [{**x, "material": r["material"]} for r in ok for x in r["exports"]
             if (x["source"], x["target"], x["requested"]) == (source, target, target_model)]
        to_table = [x["log_rmse_to_table"] for x in e]
        ratio = [x["log_rmse_to_table"] / x["fit_log_rmse_to_table"] for x in e
                 if x["log_rmse_to_table"] is not None]
        s = {"n": len(e), "target_model": e[0]["target_model"] if e else None,
             "exact": sum(x["exact"] for x in e),
             "reported_log_rmse_to_fit": _stats(x["log_rmse_to_fit"] for x in e),
             "fit_log_rmse_to_table": _stats(x["fit_log_rmse_to_table"] for x in e),
             "log_rmse_to_table": _stats(to_table),
             "to_table_over_fit": _stats(ratio),
             "colour_shift": _stats(x["sphere_colour"]["colour_shift"] for x in e
                                    if x["sphere_colour"]
                                    and x["sphere_colour"]["colour_shift"] is not None),
             "colour_shift_above_3": sum(
                 (x["sphere_colour"]["colour_shift"] or 0.0) > 3.0 for x in e
                 if x["sphere_colour"]),
             "brightness_stops": _stats(abs(x["sphere_colour"]["brightness_stops"]) for x in e
                                        if x["sphere_colour"]
                                        and x["sphere_colour"]["brightness_stops"] is not None),
             "albedo_max": _stats(max(x["albedo_max"]) for x in e),
             "albedo_above_1": sum(max(x["albedo_max"]) > 1.005 for x in e)}
        indep = [(x["log_rmse_to_table"], x["independent"]) for x in e
                 if x.get("independent") is not None and x["log_rmse_to_table"] is not None]
        if indep:
            rel = [abs(a / b - 1) for a, b in indep]
            s["reported_vs_independent"] = _stats(rel)
            s["independent_n"] = len(indep)
        if any("model_on_subset" in x for x in e):
            sub = [x for x in e if "model_on_subset" in x]
            s["materialx_vs_model_on_subset"] = _stats(
                abs(x["independent"] / x["model_on_subset"] - 1) for x in sub)
            s["materialx_max_rel_diff"] = _stats(x["materialx_max_rel_diff"] for x in sub)
        if target == "gltf":
            lo, hi = FRACTIONAL
            s["fractional_metallic"] = sum(lo < x["target_params"]["metallic"] < hi for x in e)
            s["definition_over_pseudocode"] = _stats(x["independent"] / x["pseudocode"]
                                                     for x in e)
            s["pseudocode_over_fit"] = _stats(x["pseudocode"] / x["fit_log_rmse_to_table"]
                                              for x in e)
        if target == "mitsuba":
            s["mitsuba_log_rmse_to_fit"] = _stats(x["mitsuba_log_rmse_to_fit"] for x in e)
            worst = [max(abs(d) for d in x["spectral_colour"]["relative_difference"])
                     for x in e]
            s["spectral_vs_rgb"] = _stats(worst)
            s["spectral_within_5_percent"] = sum(w <= 0.05 for w in worst)
            refused = [x["material"] for x in e if "refused" in x["spectral_colour"]]
            s["spectral_refused"] = (f"{len(refused)} ({', '.join(refused)})" if refused
                                     else "none")
            if source == "rough_conductor":
                s["mitsuba_eval_max_rel_diff"] = {
                    k: _stats(x["mitsuba_eval_max_rel_diff"][k] for x in e)
                    for k in ("random", "bins", "bins_theta_d_below_85")}
                s["eval_within_1e-4_random"] = sum(
                    x["mitsuba_eval_max_rel_diff"]["random"] <= 1e-4 for x in e)
                s["mitsuba_sphere_psnr_db_same_material"] = _stats(
                    x["mitsuba_sphere_psnr_db_same_material"] for x in e)
        if target == "gltf" and any("gltf_validator" in x for x in e):
            s["gltf_validator_errors"] = sum(x["gltf_validator"]["errors"] for x in e)
            s["gltf_validator_warnings"] = sum(x["gltf_validator"]["warnings"] for x in e)
        if target == "materialx":
            s["materialx_valid"] = sum(x["materialx_valid"] for x in e)
        out["exports"][f"{source}->{target}" + (f" ({target_model})" if target_model else "")] = s
    for group, names in (("metals", METALS), ("metallic_paints", METALLIC_PAINTS),
                         ("all", [r["material"] for r in ok])):
        gain = [1 - r["fits"]["rough_conductor"]["log_rmse"] / r["fits"]["ggx"]["log_rmse"]
                for r in ok if r["material"] in names]
        out["conductor_gain"][group] = {**_stats(gain), "better": sum(g > 0 for g in gain)}
    return out


# -- the report ------------------------------------------------------------------------


def _f(x, fmt=".4f") -> str:
    return "" if x is None else format(x, fmt)


def _range(s: dict, fmt=".4f", scale=1.0) -> str:
    if not s.get("n"):
        return "n/a"
    return (f"{s['median'] * scale:{fmt}} ({s['min'] * scale:{fmt}} .. "
            f"{s['max'] * scale:{fmt}})")


def _ratio_stats(ok: list[dict], model: str, over: str) -> dict:
    return _stats(r["fits"][model]["log_rmse"] / r["fits"][over]["log_rmse"] for r in ok)


def _markdown(rows: list[dict], summary: dict, meta: dict) -> str:
    ok = [r for r in rows if "error" not in r]
    lines = [
        "# Exports and physically bounded fits on the real materials",
        "",
        f"`{meta['command']}` ({meta['date']}, brdffit {meta['brdffit']}, Mitsuba "
        f"{meta['mitsuba']} `{meta['mitsuba_variant']}`, MaterialX {meta['materialx']}, glTF "
        f"validator {meta['gltf_validator'] or 'not run'}; {meta['machine']}): "
        f"{summary['materials']} materials in {meta['wall_s'] / 60:.1f} min"
        + (f", failed: {', '.join(summary['failed'])}" if summary["failed"] else "") + "."
        + (f" Mitsuba's RGB-vs-spectral colours re-measured {meta['spectral_remeasured']}."
           if meta.get("spectral_remeasured") else ""),
        "Default fits (16,384 samples, 1 start); `log_rmse` on every bin of the table; PSNR "
        "of the sphere renders (two lights, `brdffit.fitting.sphere`). Cells with ranges: "
        "median (min .. max) over the materials.",
        "",
        "## Physically bounded fits (`physical=True`)",
        "",
        "The bounded fit of each default fit (`brdffit.fitting.physical`): reflectances "
        "<= 1 and directional albedo <= 1 at every incidence and channel.",
        "",
        "| model | log_rmse | converged | bounded log_rmse | materials the bounds cost "
        "anything (bounds at their limit) | relative cost there | largest albedo before | "
        "after | bounded fits converged | final clamp | extra time there (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m in BOUNDED:
        s = summary["fits"][m]
        act = ", ".join(f"{k}: {v}" for k, v in s["active"].items() if v) or "none"
        lines.append(
            f"| {m} | {_range(s['log_rmse'])} | {s['converged']}/{s['log_rmse']['n']} | "
            f"{_range(s['bounded_log_rmse'])} | "
            f"{s['bounded_materials']} ({act}) | "
            f"{_range(s['relative_cost_where_bounded'], '+.1%')} | "
            f"{_range(s['albedo_max_before'], '.3f')} | "
            f"{_f(s['albedo_max_after'].get('max'), '.4f')} max | "
            f"{s['bounded_converged']}/{s['albedo_max_after']['n']} | {s['clamped']} | "
            f"{_range(s['bound_time_s'], '.2f')} |")
    lines += ["", "Every bounded fit, largest cost first:", "",
              "| material | model | log_rmse | bounded | cost | largest albedo before -> after "
              "| active bounds |", "|---|---|---|---|---|---|---|"]
    bounded = sorted(((r["fits"][m]["bounded"]["relative_cost"], r["material"], m)
                      for r in ok for m in BOUNDED if r["fits"][m]["bounded"]["relative_cost"]),
                     reverse=True)
    for cost, name, m in bounded:
        f = next(r for r in ok if r["material"] == name)["fits"][m]
        b = f["bounded"]
        lines.append(f"| {name} | {m} | {f['log_rmse']:.4f} | {b['log_rmse']:.4f} | "
                     f"{cost:+.1%} | {b['albedo_max_before']:.3f} -> {b['albedo_max_after']:.4f}"
                     f" at {b['albedo_max_theta_deg']:g} deg | {'; '.join(b['active'])} |")

    g = summary["conductor_gain"]
    lines += [
        "",
        "## The conductor against grey-f0 GGX",
        "",
        "Gain = 1 - log_rmse(rough_conductor) / log_rmse(ggx), default fits (positive: the "
        "conductor fits better).",
        "",
        "| materials | n | gain | conductor better on |",
        "|---|---|---|---|",
    ]
    for group, label in (("metals", "bare metals"), ("metallic_paints", "metallic paints"),
                         ("all", "all materials")):
        s = g[group]
        lines.append(f"| {label} | {s['n']} | {_range(s, '+.1%')} | {s['better']} |")
    lines += ["", "| metal | ggx | rough_conductor | gltf_pbr | gain |", "|---|---|---|---|---|"]
    for r in ok:
        if r["material"] in METALS + METALLIC_PAINTS:
            f = r["fits"]
            gain = 1 - f["rough_conductor"]["log_rmse"] / f["ggx"]["log_rmse"]
            lines.append(f"| {r['material']} | {f['ggx']['log_rmse']:.4f} | "
                         f"{f['rough_conductor']['log_rmse']:.4f} | "
                         f"{f['gltf_pbr']['log_rmse']:.4f} | {gain:+.1%} |")

    ex = summary["exports"]

    def renderer_rows(keys):
        out = ["| export | file carries | exact | fit's own log_rmse to the table | exported "
               "file's log_rmse to the table | ratio to the fit's | reported vs independent "
               "evaluation (max rel. diff) | lit-sphere brightness, stops | colour, "
               "CIEDE2000 | > 3 | albedo > 1 |", "|---|---|---|---|---|---|---|---|---|---|---|"]
        for key in keys:
            s = ex[key]
            ind = (f"{s['reported_vs_independent']['max']:.1e} ({s['independent_n']}/{s['n']})"
                   if "reported_vs_independent" in s else "not evaluated")
            out.append(
                f"| {key} | {s['target_model']} | {s['exact']}/{s['n']} | "
                f"{_range(s['fit_log_rmse_to_table'])} | {_range(s['log_rmse_to_table'])} | "
                f"{_range(s['to_table_over_fit'], '.2f')} | {ind} | "
                f"{_range(s['brightness_stops'], '.2f')} | {_range(s['colour_shift'], '.1f')} | "
                f"{s['colour_shift_above_3']}/{s['n']} | {s['albedo_above_1']}/{s['n']} |")
        return out

    keys = {t: [k for k in ex if k.split("->")[1].split()[0] == t]
            for t in ("mitsuba", "gltf", "materialx")}
    lines += [
        "",
        "## Fidelity of the exports, one table per renderer",
        "",
        "Every export is judged against the measured table under the renderer's own "
        "semantics: *exported file's log_rmse to the table* is what the export reports "
        "(`fidelity.log_rmse_to_table`), *independent evaluation* the same error with the "
        "file evaluated without brdffit's models (Mitsuba's `BSDF.eval`; glTF's spec "
        "written out in numpy, `brdffit.export.validate.gltf_spec_eval`; MaterialX's own "
        "shader code, `validate.materialx_eval`). *Ratio to the fit's*: the exported "
        "file's error over the source fit's own error to the table (1: nothing lost). "
        "Colour: `fidelity.sphere_colour`, the exported material's lit key-light sphere "
        "against the table's, both read through the table's bins: brightness in stops "
        "and the colour shift as CIEDE2000 at equal luminance.",
        "",
        "### Mitsuba 3",
        "",
        *renderer_rows(keys["mitsuba"]),
        "",
    ]
    for key in keys["mitsuba"]:
        s = ex[key]
        lines.append(
            f"- {key}: a sphere under a directional light (64 px, 64 samples per pixel; "
            f"{NEAR_MIRROR_SPP} where alpha < {NEAR_MIRROR_ALPHA}) renders to the same mean "
            f"colour in `scalar_rgb` and `scalar_spectral` within 5% per channel on "
            f"{s['spectral_within_5_percent']}/{s['n']} materials (worst channel difference "
            f"{_range(s['spectral_vs_rgb'], '.2%')}); the spectral form refused on "
            f"{s['spectral_refused']}.")
        ev = s.get("mitsuba_eval_max_rel_diff")
        if ev:
            lines.append(
                f"- {key}: Mitsuba's `BSDF.eval` against brdffit's model, largest relative "
                f"difference {ev['random']['max']:.1e} on 4,096 uniform direction pairs "
                f"({s['eval_within_1e-4_random']}/{s['n']} within 1e-4); on MERL bin centres "
                f"{ev['bins']['max']:.1e}, theta_d < 85 deg "
                f"{ev['bins_theta_d_below_85']['max']:.1e}"
                f"; Mitsuba's sphere against brdffit's, pixel averages: "
                f"{_range(s['mitsuba_sphere_psnr_db_same_material'], '.1f')} dB.")
    g = ex["gltf_pbr->gltf"]
    lines += [
        "",
        "### glTF 2.0",
        "",
        *renderer_rows(keys["gltf"]),
        "",
        f"- Fractional metallic (between {FRACTIONAL[0]} and {FRACTIONAL[1]}): "
        + ", ".join(f"{k} {ex[k]['fractional_metallic']}/{ex[k]['n']}" for k in keys["gltf"])
        + ". There the spec's definition and its implementation pseudocode differ.",
        "- The exported file's error under the spec's definition over its error under the "
        "pseudocode (the file was made for the definition): "
        + "; ".join(f"{k} {_range(ex[k]['definition_over_pseudocode'], '.3f')}"
                    for k in keys["gltf"])
        + ". A viewer that follows the pseudocode shows the file with an error of "
        + f"{_range(g['pseudocode_over_fit'], '.2f')} times the fit's.",
    ]
    if "gltf_validator_errors" in g:
        lines.append(f"- Khronos glTF validator: {g['gltf_validator_errors']} errors, "
                     f"{g['gltf_validator_warnings']} warnings over every document.")
    lines += [
        "",
        "### MaterialX 1.39",
        "",
        *renderer_rows(keys["materialx"]),
        "",
        "- MaterialX's own validation: "
        + ", ".join(f"{k} {ex[k]['materialx_valid']}/{ex[k]['n']}" for k in keys["materialx"])
        + ".",
        *[f"- {k}: MaterialX's generated GLSL evaluated on {MATERIALX_BINS:,} random measured "
          f"bins (one draw per light direction, so a subset); its log_rmse there against "
          f"brdffit's `standard_surface` on the same bins: "
          f"{_range(ex[k]['materialx_vs_model_on_subset'], '.1e')} relative; largest value "
          f"difference {_range(ex[k]['materialx_max_rel_diff'], '.1e')} (float32 shader). "
          "The *independent evaluation* column compares the full-table figure with that "
          "subset's, so it includes the subset's sampling."
          for k in keys["materialx"] if "materialx_vs_model_on_subset" in ex[k]],
        "- The default `standard_surface` against the ggx fit: its error to the table is "
        + _range(_ratio_stats(ok, "standard_surface", "ggx"), ".2f")
        + " times ggx's (the issue's bar: at most 1.5).",
    ]
    warn = {}
    for r in ok:
        for e in r["exports"]:
            for w in e["warnings"]:
                kind = w.split(":")[0] if ":" in w[:45] else " ".join(w.split()[:5]) + " ..."
                warn[(f"{e['source']}->{e['target']}", kind)] = warn.get(
                    (f"{e['source']}->{e['target']}", kind), 0) + 1
    lines += ["", "Warnings, by export and kind (materials):", ""]
    for (key, kind), n in sorted(warn.items()):
        lines.append(f"- {key}, `{kind}`: {n}")

    lines += [
        "",
        "## Every material",
        "",
        "log_rmse to the table of the default fits, and of the exported files (under the "
        "renderer's semantics); cost: the bounded fit's relative cost (·: no bound "
        "active); metallic: the gltf_pbr fit's; colour: the exported file's lit-sphere "
        "brightness (stops) and colour shift (CIEDE2000).",
        "",
        "| material | ggx | rough_conductor | gltf_pbr | standard_surface | cost ggx / "
        "conductor / gltf | ggx -> mitsuba | ggx -> gltf | ggx -> materialx | metallic | "
        "standard_surface colour |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['material']} | failed: {r['error'].splitlines()[-1]} "
                         "||||||||||")
            continue
        f = r["fits"]
        ex = {(e["source"], e["target"], e["requested"]): e for e in r["exports"]}
        costs = " / ".join(f"{c:+.1%}" if (c := f[m]["bounded"]["relative_cost"]) else "·"
                           for m in BOUNDED)
        c = ex["standard_surface", "materialx", None]["sphere_colour"] or {}
        colour = (f"{c.get('brightness_stops') or 0:+.2f} stops, "
                  f"dE {c.get('colour_shift') or 0:.1f}")
        lines.append(
            f"| {r['material']} | " + " | ".join(f"{f[m]['log_rmse']:.4f}" for m in MODELS)
            + f" | {costs} | "
            + " | ".join(f"{ex['ggx', t, None]['log_rmse_to_table']:.4f}"
                         for t in ("mitsuba", "gltf", "materialx"))
            + f" | {ex['gltf_pbr', 'gltf', None]['target_params']['metallic']:.2f} | {colour} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.exports")
    p.add_argument("--materials", help="comma-separated names (default: all 100)")
    p.add_argument("--out", default=OUT, help="folder of exports.json and exports.md")
    p.add_argument("--spectral-only", action="store_true",
                   help="re-measure only the Mitsuba RGB-vs-spectral colours of the exports "
                        "in OUT/exports.json (after a change to the spectral form)")
    p.add_argument("--gltf-validator", default=DEFAULT_VALIDATOR,
                   help="the gltf-validator npm package's folder (skipped where absent)")
    args = p.parse_args(argv)
    if args.spectral_only:
        return _spectral_only(args.out)
    import platform
    import shutil

    import MaterialX
    import mitsuba

    import brdffit
    from brdffit import jsonout
    from brdffit.export import validate
    from data_synth import nbrdf

    names = args.materials.split(",") if args.materials else list(nbrdf.material_names())
    validator = args.gltf_validator
    if not (os.path.isdir(validator) and shutil.which("node")):
        print(f"glTF validator not found at {validator}: skipped", file=sys.stderr)
        validator = None
    t0 = time.perf_counter()
    rows = []
    for i, name in enumerate(names):
        ts = time.perf_counter()
        try:
            rows.append(material_row(name, validator))
        except Exception:  # noqa: BLE001 - one material's failure is reported, not fatal
            rows.append({"material": name, "error": traceback.format_exc()})
            print(f"[{i + 1}/{len(names)}] {name}: FAILED\n{rows[-1]['error']}", file=sys.stderr,
                  flush=True)
            continue
        f = rows[-1]["fits"]
        print(f"[{i + 1}/{len(names)}] {name} {time.perf_counter() - ts:.1f} s (total "
              f"{(time.perf_counter() - t0) / 60:.1f} min): "
              + ", ".join(f"{m} {f[m]['log_rmse']:.4f}"
                          + (f" bounded {f[m]['bounded']['relative_cost']:+.1%}"
                             if f[m].get("bounded", {}).get("relative_cost") else "")
                          for m in MODELS),
              file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    meta = {"date": datetime.now(UTC).strftime("%Y-%m-%d"), "brdffit": brdffit.__version__,
            "mitsuba": mitsuba.__version__, "mitsuba_variant": validate.mitsuba().variant(),
            "materialx": MaterialX.getVersionString(),
            "gltf_validator": _validator_version(validator),
            "machine": f"{os.cpu_count()} cores, {platform.machine()}, shared",
            "command": "python -m bench.exports"
                       + (f" --materials {args.materials}" if args.materials else ""),
            "wall_s": wall}
    summary = summarise(rows)
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "exports.json"), "w") as f:
        f.write(jsonout.dumps({"meta": meta, "summary": summary, "materials": rows}, indent=1))
    with open(os.path.join(args.out, "exports.md"), "w") as f:
        f.write(_markdown(rows, summary, meta))
    print(f"done: {len(rows)} materials in {wall / 60:.1f} min", file=sys.stderr)
    return 0


def _spectral_only(out: str) -> int:
    """Re-measure ``spectral_colour`` of every Mitsuba export in ``out/exports.json`` and
    rewrite both reports; the rest of the run is kept as it was."""
    import json

    from brdffit import jsonout

    path = os.path.join(out, "exports.json")
    with open(path) as f:
        data = json.load(f)
    t0 = time.perf_counter()
    for i, row in enumerate(data["materials"]):
        for e in row.get("exports", []):
            if e["target"] == "mitsuba":
                e["spectral_colour"] = _spectral_agreement(e["target_params"])
        print(f"[{i + 1}/{len(data['materials'])}] {row['material']}", file=sys.stderr,
              flush=True)
    data["meta"]["spectral_remeasured"] = (
        f"{datetime.now(UTC).strftime('%Y-%m-%d %H:%M')} UTC, python -m bench.exports "
        f"--spectral-only, {(time.perf_counter() - t0) / 60:.1f} min")
    data["summary"] = summarise(data["materials"])
    with open(path, "w") as f:
        f.write(jsonout.dumps(data, indent=1))
    with open(os.path.join(out, "exports.md"), "w") as f:
        f.write(_markdown(data["materials"], data["summary"], data["meta"]))
    return 0


def _validator_version(folder: str | None) -> str | None:
    if folder is None:
        return None
    import json

    try:
        with open(os.path.join(folder, "package.json")) as f:
            return json.load(f).get("version")
    except OSError:
        return None


if __name__ == "__main__":
    sys.exit(main())
