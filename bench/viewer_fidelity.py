"""Does the fidelity brdffit reports for a viewer match what the viewer shows? Real
materials exported to glTF, rendered by three.js in headless Chromium (and, for a
layered model, by Blender's Cycles), each pixel compared with the measured table.

    python -m bench.viewer_fidelity [--materials a,b,...] [--size 256]
    python -m bench.viewer_fidelity --model gltf_clearcoat [--materials ...] [--size 128]

For each material: the default fit of ``--model`` (``gltf_pbr``, or a layered glTF
model: ``gltf_clearcoat``, ``gltf_sheen``, ``gltf_iridescence``, fitted from its
``gltf_pbr`` fit), exported to glTF (the spec's file); three.js 0.187.0 renders it
through the file's own camera and light (``brdffit.export.validate.threejs_render``;
the npm package in ``.tools/threejs``, as tests/test_export_viewers.py installs it), and
for a layered model Blender 3.4 too (``validate.blender_import``, Cycles, 128 samples).
On the sphere's pixels away from the rim, each of these is compared with the table's
own radiance there (its nearest bin):

- the render itself;
- brdffit's model of that viewer's shading of the file (what ``fidelity.viewers[...]``
  is computed with: ``gltf_threejs`` and its layered twins with three.js's per-pixel
  roughness term, ``gltf_blender`` and its twins);
- the spec's definition (what ``fidelity.log_rmse_to_table`` reports).

Error: the RMS over pixels of ``log(1 + L/pi) - log(1 + L_table/pi)`` (L the radiance
under irradiance pi: ``f cos_i``, the log_rmse's own compression). Colour: each
channel's mean radiance over the same pixels, the model's against the render's.

Writes bench/results/viewer_fidelity.md (``gltf_pbr``), or
viewer_fidelity_<model>.md.
"""

from __future__ import annotations

import argparse
import os
import sys
from datetime import UTC, datetime

import numpy as np

MATERIALS = ("red-plastic", "gold-metallic-paint", "pink-fabric", "pink-felt", "white-acrylic",
             "blue-metallic-paint", "green-metallic-paint", "yellow-paint",
             "silver-metallic-paint", "alum-bronze")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
THREEJS = os.path.join(ROOT, ".tools", "threejs", "node_modules", "three")


def measure(name: str, size: int) -> dict:
    """The core material (``gltf_pbr``) in three.js: the original table's row."""
    from brdffit import fit
    from brdffit.export import export, validate
    from data_synth import nbrdf

    table = nbrdf.make_table(name)
    r = fit(table, "gltf_pbr")
    e = export(r, "gltf", table=table)
    image = validate.threejs_render(e.material, THREEJS, size=size)[..., :3].reshape(-1, 3)
    error, inner = _pixel_error(table, size)
    shown = {"three.js": image,
             **{m: validate.preview_radiance(m, e.target_params, size)
                for m in ("gltf_threejs", "gltf_pbr")}}
    colour = shown["gltf_threejs"][inner].mean(0) / image[inner].mean(0) - 1
    return {"material": name, "metallic": float(e.target_params["metallic"]),
            "pixels": int(inner.sum()), **{k: error(v) for k, v in shown.items()},
            "colour": colour.tolist(),
            "reported": {v: (e.fidelity["viewers"][v] or {}).get("log_rmse_to_table")
                         for v in ("spec", "threejs")}}


def _pixel_error(table, size: int):
    """The error of a radiance image against ``table``'s nearest bins on the preview
    sphere's measured pixels away from the rim (a function), and those pixels."""
    from brdffit.export import validate
    from brdffit.io.angles import SHAPE, dirs_to_half_diff, half_diff_to_bins

    wi, wo, hit, _ = validate.gltf_preview_pairs(size)
    bins = np.ravel_multi_index(half_diff_to_bins(*dirs_to_half_diff(wi, wo)), SHAPE)
    measured = table.mask.reshape(-1)[bins]
    inner = hit & (wi[:, 2] > 0.05) & (wo[:, 2] > 0.1) & measured
    truth = table.rgb.reshape(3, -1)[:, bins].T * np.pi * np.clip(wi[:, 2:3], 0.0, None)

    def error(rad):
        d = np.log1p(rad[inner] / np.pi) - np.log1p(truth[inner] / np.pi)
        return float(np.sqrt(np.mean(d * d)))

    return error, inner


def measure_layered(name: str, model: str, size: int) -> dict:
    """A layered fit's spec file in three.js and in Blender: per viewer, the render's
    error, the error of brdffit's model of that viewer (the one ``fidelity.viewers``
    reports), and the spec's."""
    import tempfile
    from pathlib import Path

    from brdffit import fit
    from brdffit.export import export, validate
    from data_synth import nbrdf

    table = nbrdf.make_table(name)
    r = fit(table, model, parent_fit=fit(table, "gltf_pbr"))
    e = export(r, "gltf", table=table)
    error, inner = _pixel_error(table, size)
    renders = {"threejs": validate.threejs_render(e.material, THREEJS, size=size)}
    with tempfile.TemporaryDirectory() as tmp:
        (file, data), = e.file_bytes().items()
        (Path(tmp) / file).write_bytes(data)
        renders["blender"] = validate.blender_import(Path(tmp) / file, size=size,
                                                     samples=128)["image"]
    row = {"material": name, "spec": error(validate.preview_radiance(model, e.target_params,
                                                                     size)),
           "layer": {k: e.target_params[k] for k in e.target_params
                     if k not in ("base_color", "metallic", "roughness")}}
    for viewer, image in renders.items():
        shown = image[..., :3].reshape(-1, 3)
        v = e.fidelity["viewers"][viewer]
        params = {k: p for k, p in e.target_params.items() if k not in v.get("ignores", ())}
        ours = validate.preview_radiance(v["model"], params, size)
        row[viewer] = {"model": v["model"], "render": error(shown), "ours": error(ours),
                       "median_pixel": float(np.median(np.abs(
                           ours[inner] / np.maximum(shown[inner], 1e-12) - 1)))}
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.viewer_fidelity")
    ap.add_argument("--materials", default=",".join(MATERIALS))
    ap.add_argument("--size", type=int, default=None,
                    help="pixels per side (default 256; 128 for a layered model, which "
                         "Cycles renders too)")
    ap.add_argument("--model", default="gltf_pbr",
                    help="gltf_pbr, or a layered glTF model (gltf_clearcoat, gltf_sheen, "
                         "gltf_iridescence)")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results"))
    args = ap.parse_args(argv)
    if not os.path.isdir(THREEJS):
        print(f"three.js is not installed in {THREEJS}: run tests/test_export_viewers.py "
              "once (it installs three@0.187.0 there)", file=sys.stderr)
        return 2
    if args.model != "gltf_pbr":
        return _layered_report(args)
    args.size = args.size or 256
    rows = []
    for name in args.materials.split(","):
        rows.append(measure(name, args.size))
        x = rows[-1]
        print(f"{name}: three.js {x['three.js']:.4f}, gltf_threejs {x['gltf_threejs']:.4f}, "
              f"gltf_pbr {x['gltf_pbr']:.4f}", flush=True)
    lines = [
        "# The reported three.js fidelity against three.js's own render", "",
        f"`python -m bench.viewer_fidelity` ({datetime.now(UTC).isoformat(timespec='seconds')}"
        f", {args.size} px): default `gltf_pbr` fits of real materials exported to glTF, "
        "rendered by three.js 0.187.0 (headless Chromium, SwiftShader), every sphere pixel "
        "away from the rim compared with the table's nearest bin: RMS of log(1 + L/pi) "
        "differences. *model / render*: brdffit's `gltf_threejs` error over the render's "
        "(1: the model predicts three.js's error exactly); *spec / render*: the same for "
        "the spec's definition. Colour: the model's mean radiance per channel against the "
        "render's.", "",
        "| material | metallic | pixels | three.js render | gltf_threejs model | model / render "
        "| gltf_pbr (spec) | spec / render | colour, model vs render (R, G, B) |",
        "|---|---|---|---|---|---|---|---|---|"]
    for x in rows:
        lines.append(
            f"| {x['material']} | {x['metallic']:.2f} | {x['pixels']} | {x['three.js']:.4f} | "
            f"{x['gltf_threejs']:.4f} | {x['gltf_threejs'] / x['three.js']:.3f} | "
            f"{x['gltf_pbr']:.4f} | {x['gltf_pbr'] / x['three.js']:.3f} | "
            + " ".join(f"{c:+.2%}" for c in x["colour"]) + " |")
    lines.append("")
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "viewer_fidelity.md"), "w") as f:
        f.write("\n".join(lines))
    print("\n".join(lines))
    return 0


def _layered_report(args) -> int:
    size = args.size or 128
    rows = []
    for name in args.materials.split(","):
        rows.append(measure_layered(name, args.model, size))
        print(rows[-1], flush=True)
    lines = [
        f"# A `{args.model}` export in three.js and Blender against the reported fidelity",
        "",
        f"`python -m bench.viewer_fidelity --model {args.model}` "
        f"({datetime.now(UTC).isoformat(timespec='seconds')}, {size} px): default "
        f"`{args.model}` fits of real materials (from their `gltf_pbr` fit), exported to "
        "glTF (the spec's file), rendered by three.js 0.187.0 (headless Chromium) and by "
        "Blender 3.4's importer and Cycles (128 samples); every sphere pixel away from the "
        "rim compared with the table's nearest bin: RMS of log(1 + L/pi) differences. Per "
        "viewer: the render's error, that of the model `fidelity.viewers` reports with "
        "(*model*), their ratio, and the median pixel's relative difference between the "
        "model and the render. *spec*: the same for the spec's definition.", "",
        "| material | the layer | spec | three.js render | model | / render | median pixel "
        "| Blender render | model | / render | median pixel |",
        "|---|---|---|---|---|---|---|---|---|---|---|"]
    for x in rows:
        layer = ", ".join(f"{k} {np.round(np.asarray(v), 3).tolist()}"
                          for k, v in x["layer"].items())
        cells = []
        for viewer in ("threejs", "blender"):
            v = x[viewer]
            cells += [f"{v['render']:.4f}", f"{v['ours']:.4f} (`{v['model']}`)",
                      f"{v['ours'] / v['render']:.3f}", f"{v['median_pixel']:.2%}"]
        lines.append(f"| {x['material']} | {layer} | {x['spec']:.4f} | " + " | ".join(cells)
                     + " |")
    lines.append("")
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, f"viewer_fidelity_{args.model}.md"), "w") as f:
        f.write("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
