"""Exports as the renderers draw them, beside the measured sphere: a picture to look at.

    python -m bench.export_spheres [--materials a,b,c] [--out docs/img/export_spheres.png]

Per material (tables rebuilt offline from the shipped networks, ``data_synth.nbrdf``),
one row, the key light of ``brdffit.fitting.sphere`` and one exposure (the measured
sphere's): the measured table; the ``ggx`` fit exported to Mitsuba, rendered by Mitsuba
in ``scalar_rgb`` (``NAME.xml``) and in ``scalar_spectral`` (``NAME_spectral.xml``);
exported to MaterialX (``standard_surface``), shaded by MaterialX's own generated GLSL
on headless OpenGL; exported to glTF, evaluated by the spec's definition written in
numpy. Each panel's title carries the export's own figures: its log_rmse to the table
and its colour error on the key-light sphere.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT = ("gold-metallic-paint", "red-plastic", "blue-fabric")
SIZE = 128


def _row(name: str) -> tuple[list[np.ndarray], list[str]]:
    from bench.exports import _table
    from brdffit import fit
    from brdffit.export import export, mitsuba, validate
    from brdffit.fitting import sphere

    table = _table(name)
    light = sphere.LIGHTS[0][1]
    measured, lit = sphere.render_table(table, light, SIZE)
    wi, wo, _ = sphere.sphere_directions(SIZE, light)
    r = fit(table, "ggx")
    images, titles = [np.nan_to_num(measured)], [f"{name}\nmeasured"]

    def caption(label, e):
        sc = e.fidelity["sphere_colour"] or {}
        c = (f"{sc.get('brightness_stops') or 0:+.2f} stops, "
             f"dE {sc.get('colour_shift') or 0:.1f}")
        return f"{label}\nlog_rmse {e.fidelity['log_rmse_to_table']:.4f}, colour {c}"

    e = export(r, "mitsuba", table=table)
    images.append(validate.mitsuba_sphere(e.material, light, SIZE, 64, variant="scalar_rgb"))
    titles.append(caption("Mitsuba scalar_rgb", e))
    images.append(validate.mitsuba_sphere(mitsuba.load_dict(e.target_params, spectral=True),
                                          light, SIZE, 64, variant="scalar_spectral"))
    titles.append("Mitsuba scalar_spectral\n(NAME_spectral.xml)")
    x = export(r, "materialx", table=table)
    img = np.zeros((SIZE, SIZE, 3))
    img[lit] = validate.materialx_eval(x.material, wi[lit], wo[lit])
    images.append(sphere.radiance(img, wi))
    titles.append(caption("MaterialX GLSL (standard_surface)", x))
    g = export(r, "gltf", table=table)
    img = np.zeros((SIZE, SIZE, 3))
    img[lit] = validate.gltf_spec_eval(g.target_params, wi[lit], wo[lit])
    images.append(sphere.radiance(img, wi))
    titles.append(caption("glTF spec definition", g))
    return images, titles


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.export_spheres")
    p.add_argument("--materials", default=",".join(DEFAULT))
    p.add_argument("--out", default=os.path.join(ROOT, "docs", "img", "export_spheres.png"))
    args = p.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from brdffit.fitting import sphere

    names = args.materials.split(",")
    fig, axes = plt.subplots(len(names), 5, figsize=(15, 3.4 * len(names)), squeeze=False)
    for row, name in zip(axes, names, strict=True):
        images, titles = _row(name)
        typical = np.median(images[0][images[0].sum(-1) > 0] @ sphere.LUMINANCE)
        exposure = 0.35 / max(float(typical), 1e-6)
        for ax, img, title in zip(row, images, titles, strict=True):
            ax.imshow(np.clip(sphere.tonemap(img, exposure), 0, 1))
            ax.set_title(title, fontsize=9)
            ax.set_axis_off()
    fig.suptitle("ggx fits exported, as each renderer draws them (key light 45° above-left, "
                 "the measured sphere's exposure)", fontsize=11)
    fig.tight_layout()
    fig.savefig(args.out, dpi=90)
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
