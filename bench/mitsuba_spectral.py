"""The Mitsuba export in Mitsuba's RGB and spectral variants: mean sphere colour.

    python -m bench.mitsuba_spectral [--spp N] [--size PX] [--before] [--materials a,b]

For analytic ``rough_conductor`` parameter sets and the exports of default fits of
real materials (tables rebuilt with ``data_synth.nbrdf``; ``red-plastic:ggx`` is its
``ggx`` fit, refitted as ``rough_conductor`` by the export): ``validate.mitsuba_sphere`` (white
directional light, the first of ``brdffit.fitting.sphere.LIGHTS``) in ``scalar_rgb``
with ``load_dict(params)`` and in ``scalar_spectral`` with ``load_dict(params,
spectral=True)`` (``--before``: the RGB form in both, what the export wrote before the
spectral form existed); prints each mean colour and the spectral one's relative
difference per channel. Then ``spectral_ior.fit_spectra``'s error and time on the
100 real materials' ``rough_conductor`` fits of ``bench/results/exports.json``
(``--all100``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ANALYTIC = {
    "white diffuse (the light)": {"eta": [1.5] * 3, "k": [0.0] * 3, "alpha": 0.3,
                                  "kd": [1.0] * 3, "weight": 1.0},
    "eta [5, 10, 10], k 0": {"eta": [5.0, 10.0, 10.0], "k": [0.0] * 3, "alpha": 0.3,
                             "kd": [0.0] * 3, "weight": 0.0},
    "eta 0.2, k 3.9 (grey gold-like)": {"eta": [0.2] * 3, "k": [3.9] * 3, "alpha": 0.3,
                                        "kd": [0.0] * 3, "weight": 0.0},
    "gold (eta, k at R, G, B)": {"eta": [0.143, 0.374, 1.442], "k": [3.983, 2.385, 1.603],
                                 "alpha": 0.2, "kd": [0.0] * 3, "weight": 0.0},
    "red diffuse": {"eta": [1.5] * 3, "k": [0.0] * 3, "alpha": 0.3,
                    "kd": [0.8, 0.1, 0.05], "weight": 1.0},
}
REAL = ("gold-metallic-paint", "red-plastic", "blue-fabric", "chrome-steel", "red-plastic:ggx")


def _real(source: str) -> dict:
    """The Mitsuba export's parameters of a default fit, ``material[:model]`` (default
    model ``rough_conductor``, exported exactly; another is refitted as one)."""
    from brdffit.export import export
    from brdffit.fitting.pipeline import fit
    from data_synth import nbrdf

    material, _, model = source.partition(":")
    r = fit(nbrdf.make_table(material), model or "rough_conductor")
    return export(r, "mitsuba").target_params


def mean_colours(params: dict, size: int = 64, spp: int = 64,
                 before: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Mean linear sRGB of the key-light sphere of ``rough_conductor`` ``params`` in
    ``scalar_rgb`` (the RGB form) and in ``scalar_spectral`` (the spectral form; with
    ``before``, the RGB form too). Raises ``SpectralExportError`` where it is refused."""
    from brdffit.export import mitsuba
    from brdffit.export import validate as check
    from brdffit.fitting import sphere as render

    light = render.LIGHTS[0][1]
    rgb_form = mitsuba.load_dict(params)
    spectral_form = rgb_form if before else mitsuba.load_dict(params, spectral=True)
    a = check.mitsuba_sphere(rgb_form, light, size=size, spp=spp, variant="scalar_rgb")
    b = check.mitsuba_sphere(spectral_form, light, size=size, spp=spp, variant="scalar_spectral")
    return a.reshape(-1, 3).mean(0), b.reshape(-1, 3).mean(0)


def spheres(cases: dict, size: int, spp: int, before: bool) -> None:
    for name, params in cases.items():
        ma, mb = mean_colours(params, size, spp, before)
        rel = " / ".join(f"{100 * x:+.1f}%" for x in mb / ma - 1)
        print(f"{name:34s} rgb {np.round(ma, 4)} spectral {np.round(mb, 4)}  {rel}", flush=True)


def all100() -> None:
    from brdffit.export import spectral_ior
    from brdffit.export.mitsuba import SPECTRAL_TOLERANCE

    path = Path(__file__).parent / "results" / "exports.json"
    errors, times = [], []
    for m in json.loads(path.read_text())["materials"]:
        p = m["fits"]["rough_conductor"]["params"]
        t = time.perf_counter()
        r = spectral_ior.fit_spectra(p["eta"], p["k"])
        times.append(time.perf_counter() - t)
        errors.append(r.error)
        print(f"{m['material']:28s} error {r.error:.2e}  {times[-1]:.2f} s", flush=True)
    e, t = np.array(errors), np.array(times)
    print(f"{e.size} materials: error median {np.median(e):.2e}, max {e.max():.2e}, "
          f"> {SPECTRAL_TOLERANCE:g}: {(e > SPECTRAL_TOLERANCE).sum()}; "
          f"time median {np.median(t):.2f} s, max {t.max():.2f} s")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.mitsuba_spectral")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--before", action="store_true")
    ap.add_argument("--materials", default=",".join(REAL))
    ap.add_argument("--all100", action="store_true")
    a = ap.parse_args(argv)
    if a.all100:
        all100()
        return 0
    cases = dict(ANALYTIC)
    cases.update({m: _real(m) for m in a.materials.split(",") if m})
    spheres(cases, a.size, a.spp, a.before)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
