"""``brdffit models``: list the models, their parameters and ranges."""

from __future__ import annotations

from brdffit import jsonout, models


def add_arguments(p) -> None:
    p.add_argument("--json", action="store_true", help="machine-readable output")


def run(args) -> int:
    info = models.describe()
    if args.json:
        print(jsonout.dumps(info, indent=2))
        return 0
    for m in info:
        print(f"{m['name']}  ({m['n_params']} values)  {m['doc']}")
        for p in m["params"]:
            bounded = p.get("physical_upper")
            note = ("" if bounded is None or bounded == p["upper"]
                    else f"  (<= {bounded:g} in a --physical fit)")
            print(f"    {p['name']:<6} {p['range']:<22} {p['doc']}{note}")
    return 0
