"""Layered materials beside their base, on the sphere: a picture to look at (issue 40).

    python -m bench.layered_spheres [--out docs/img/layered_spheres.png]
                                    [--rows material:base:layered,...]

Per row, a real material (rebuilt offline from the shipped networks,
``data_synth.nbrdf``) under the key light and under the grazing light of brdffit's
sphere plots: the measured table, the base fit and the layered fit from it
(``parent_fit``), default options, every panel at the one exposure of
``brdffit.view.plots`` (a white diffuse surface facing the light is mid-grey). Each
fit's title carries its model, log_rmse, sphere PSNR and verdict. The default rows: a
car paint under a clear coat, a fabric with a sheen, a pearlescent paint and a
colour-changing paint under a thin film, a plastic under Mitsuba's coat.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_ROWS = (
    ("gold-metallic-paint3", "gltf_pbr", "gltf_clearcoat"),
    ("light-brown-fabric", "gltf_pbr", "gltf_sheen"),
    ("pearl-paint", "gltf_pbr", "gltf_iridescence"),
    ("color-changing-paint1", "gltf_pbr", "gltf_iridescence"),
    ("green-plastic", "principled", "principled_clearcoat"),
)
SIZE = 160


def _title(r) -> str:
    q = r.quality or {}
    return (f"{r.model}\nlog_rmse {r.error['log_rmse']:.4f}, {r.error['psnr_db']:.1f} dB, "
            f"{q.get('verdict', '?')}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.layered_spheres")
    p.add_argument("--out", default=os.path.join(ROOT, "docs", "img", "layered_spheres.png"))
    p.add_argument("--rows", default=",".join(":".join(r) for r in DEFAULT_ROWS),
                   help="material:base:layered, comma separated")
    args = p.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from brdffit.fitting.pipeline import fit
    from brdffit.view.plots import SPHERE_LIGHTS, _composite, sphere_images
    from data_synth import nbrdf

    rows = [tuple(r.split(":")) for r in args.rows.split(",") if r]
    lights = SPHERE_LIGHTS[:2]
    fig, axes = plt.subplots(len(rows), 3 * len(lights), squeeze=False,
                             figsize=(3.0 * 3 * len(lights), 3.3 * len(rows)))
    background = np.zeros(3)
    for row, (name, base_name, layered_name) in zip(axes, rows, strict=True):
        table = nbrdf.make_table(name)
        base = fit(table, base_name)
        layered = fit(table, layered_name, parent_fit=base)
        print(f"{name}: {base_name} {base.error['log_rmse']:.4f} {base.quality['verdict']} "
              f"-> {layered_name} {layered.error['log_rmse']:.4f} "
              f"{layered.quality['verdict']}", flush=True)
        for k, (label, light) in enumerate(lights):
            measured, base_img, coverage, _ = sphere_images(table, base, light, SIZE)
            _, layered_img, _, _ = sphere_images(table, layered, light, SIZE)
            panels = ((measured, f"{name}\nmeasured"), (base_img, _title(base)),
                      (layered_img, _title(layered)))
            for j, (img, title) in enumerate(panels):
                ax = row[3 * k + j]
                ax.imshow(_composite(img, coverage, background), interpolation="bilinear")
                ax.set_title(title, fontsize=8)
                ax.set_xticks([])
                ax.set_yticks([])
            row[3 * k].set_ylabel(label.replace("\n", " "), fontsize=8)
    fig.suptitle("Layered fits beside their base: key light (left three), grazing light "
                 "(right three); one exposure for all", fontsize=11)
    fig.tight_layout()
    fig.savefig(args.out, dpi=80)
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
