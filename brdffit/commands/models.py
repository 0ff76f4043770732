"""``brdffit models``: list the models, their parameters and ranges."""

from __future__ import annotations

import sys

from .. import jsonout, models


def add_arguments(p) -> None:
    p.add_argument("--json", action="store_true", help="machine-readable output")


def describe() -> list[dict]:
    """Every registered model as plain data (also served by the API)."""
    return [
        {
            "name": m.name,
            "params": [
                {
                    "name": s.name,
                    "size": s.size,
                    "range": s.describe_range(),
                    "lower": s.lower,
                    "upper": s.upper,
                    "doc": s.doc,
                }
                for s in m.param_specs
            ],
            "n_params": m.n_params,
            "doc": _summary(m),
        }
        for m in models.REGISTRY.values()
    ]


def _summary(model) -> str:
    """First line of the model module's docstring (its formula)."""
    doc = sys.modules[type(model).__module__].__doc__ or model.name
    return doc.strip().splitlines()[0]


def run(args) -> int:
    info = describe()
    if args.json:
        print(jsonout.dumps(info, indent=2))
        return 0
    for m in info:
        print(f"{m['name']}  ({m['n_params']} values)  {m['doc']}")
        for p in m["params"]:
            print(f"    {p['name']:<6} {p['range']:<22} {p['doc']}")
    return 0
