"""Does the fidelity brdffit reports for three.js match what three.js shows? Real
materials exported to glTF, rendered by three.js in headless Chromium, each pixel
compared with the measured table.

    python -m bench.viewer_fidelity [--materials a,b,...] [--size 256]

For each material: the default ``gltf_pbr`` fit, exported to glTF (the spec's file);
three.js 0.187.0 renders it through the file's own camera and light
(``brdffit.export.validate.threejs_render``; the npm package in ``.tools/threejs``, as
tests/test_export_viewers.py installs it). On the sphere's pixels away from the rim,
each of these is compared with the table's own radiance there (its nearest bin):

- ``three.js``: the render itself;
- ``gltf_threejs``: brdffit's model of three.js's shading (what
  ``fidelity.viewers.threejs`` is computed with), with three.js's per-pixel roughness
  term;
- ``gltf_pbr``: the spec's definition (what ``fidelity.log_rmse_to_table`` reports).

Error: the RMS over pixels of ``log(1 + L/pi) - log(1 + L_table/pi)`` (L the radiance
under irradiance pi: ``f cos_i``, the log_rmse's own compression). Colour: each
channel's mean radiance over the same pixels, the model's against the render's.

Writes bench/results/viewer_fidelity.md.
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
    from brdffit import fit
    from brdffit.export import export, validate
    from brdffit.io.angles import SHAPE, dirs_to_half_diff, half_diff_to_bins
    from data_synth import nbrdf

    table = nbrdf.make_table(name)
    r = fit(table, "gltf_pbr")
    e = export(r, "gltf", table=table)
    image = validate.threejs_render(e.material, THREEJS, size=size)[..., :3].reshape(-1, 3)
    wi, wo, hit, _ = validate.gltf_preview_pairs(size)
    bins = np.ravel_multi_index(half_diff_to_bins(*dirs_to_half_diff(wi, wo)), SHAPE)
    measured = table.mask.reshape(-1)[bins]
    inner = hit & (wi[:, 2] > 0.05) & (wo[:, 2] > 0.1) & measured
    truth = table.rgb.reshape(3, -1)[:, bins].T * np.pi * np.clip(wi[:, 2:3], 0.0, None)
    shown = {"three.js": image,
             **{m: validate.preview_radiance(m, e.target_params, size)
                for m in ("gltf_threejs", "gltf_pbr")}}

    def error(rad):
        d = np.log1p(rad[inner] / np.pi) - np.log1p(truth[inner] / np.pi)
        return float(np.sqrt(np.mean(d * d)))

    colour = shown["gltf_threejs"][inner].mean(0) / image[inner].mean(0) - 1
    return {"material": name, "metallic": float(e.target_params["metallic"]),
            "pixels": int(inner.sum()), **{k: error(v) for k, v in shown.items()},
            "colour": colour.tolist(),
            "reported": {v: (e.fidelity["viewers"][v] or {}).get("log_rmse_to_table")
                         for v in ("spec", "threejs")}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.viewer_fidelity")
    ap.add_argument("--materials", default=",".join(MATERIALS))
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results"))
    args = ap.parse_args(argv)
    if not os.path.isdir(THREEJS):
        print(f"three.js is not installed in {THREEJS}: run tests/test_export_viewers.py "
              "once (it installs three@0.187.0 there)", file=sys.stderr)
        return 2
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


if __name__ == "__main__":
    sys.exit(main())
