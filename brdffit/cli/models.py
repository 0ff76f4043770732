"""``brdffit models``: list the models, their parameters and ranges."""

from __future__ import annotations

from brdffit import jsonout, models
from brdffit.models.catalogue import MONO_SUFFIX


def add_arguments(p) -> None:
    p.add_argument("--json", action="store_true", help="machine-readable output")


def run(args) -> int:
    info = models.describe()
    if args.json:
        print(jsonout.dumps(info, indent=2))
        return 0
    for m in info:
        print(f"{m['name']}  ({m['n_params']} values)  {m['doc']}")
        # columns as wide as this model's longest name and range (standard_surface's
        # specular_roughness pushed a fixed-width column out of line)
        width = max(6, *(len(p["name"]) for p in m["params"]))
        span = max(22, *(len(p["range"]) for p in m["params"]))
        for p in m["params"]:
            bounded = p.get("physical_upper")
            note = ("" if bounded is None or bounded == p["upper"]
                    else f"  (<= {bounded:g} in a --physical fit)")
            print(f"    {p['name']:<{width}} {p['range']:<{span}} {p['doc']}{note}")
        if m["mono"]:
            print(f"    also {m['name']}{MONO_SUFFIX} ({m['mono_n_params']} values): "
                  f"{', '.join(m['mono_params'])} "
                  f"{'each ' if len(m['mono_params']) > 1 else ''}one grey value")
    return 0
