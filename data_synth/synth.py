"""Write MERL tables from the analytic models of ``brdffit.models``.

Each bin holds the model's value at the bin centre (docs/models.md's sample
position); bins whose centre is below the horizon are written unmeasured
(raw -1), as MERL does. Optional degradations, in this order:

- ``noise``: multiplicative Gaussian, value * max(0, 1 + noise * N(0, 1));
- ``missing``: that fraction of the measured bins, chosen at random, unmeasured;
- ``keep``: a boolean mask over the flat bins (a preset's region, e.g. grazing only).

A table may sum several components (two lobes): ``Component(model, params)``.
"""

from __future__ import annotations

import functools
import json
import os
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from brdffit import jsonout, models, runtime
from brdffit.io import merl
from brdffit.io.grid import bin_grid

DEFAULT_PARAMS: dict[str, dict] = {
    "lambert": {"kd": [0.5, 0.35, 0.2]},
    "oren_nayar": {"kd": [0.5, 0.35, 0.2], "sigma": 0.5},
    "phong": {"kd": [0.2, 0.15, 0.1], "ks": [0.3, 0.3, 0.3], "n": 80.0},
    "blinn_phong": {"kd": [0.2, 0.15, 0.1], "ks": [0.3, 0.3, 0.3], "n": 120.0},
    "ggx": {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.8, 0.8], "alpha": 0.15, "f0": 0.6},
    "beckmann": {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.8, 0.8], "alpha": 0.15, "f0": 0.6},
    "beckmann_dielectric": {"kd": [0.2, 0.1, 0.05], "ks": [8.0] * 3, "alpha": 0.15, "eta": 1.5},
    "ggx_dielectric": {"kd": [0.2, 0.1, 0.05], "ks": [8.0] * 3, "alpha": 0.15, "eta": 1.5},
    "ggx2": {
        "kd": [0.1, 0.08, 0.05],
        "ks1": [0.5, 0.5, 0.5],
        "alpha1": 0.03,
        "ks2": [0.4, 0.4, 0.4],
        "alpha2": 0.3,
        "f0": 0.8,
    },
}


@dataclass(frozen=True)
class Component:
    model: str
    params: dict


@runtime.in_float64
def render_values(components: list[Component]) -> np.ndarray:
    """Model values at every bin centre, flat (3, 90*90*180); 0 below the horizon."""
    g = bin_grid()
    idx = np.flatnonzero(g.above_horizon)
    wi, wo = jnp.asarray(g.wi[idx]), jnp.asarray(g.wo[idx])
    total = np.zeros((idx.size, 3))
    for c in components:
        m = models.get(c.model)
        p = {k: jnp.asarray(v) for k, v in m.check_params(c.params).items()}
        total += np.asarray(_compiled(m)(p, wi, wo))
    out = np.zeros((3, g.weight.size))
    out[:, idx] = total.T
    return out


def _compiled(m):
    """``m`` compiled for the grid's ~1.2M direction pairs: one program per model and
    process, where op-by-op evaluation made each table's 1.2M-long temporaries one
    by one (a table of rough_plastic took 4.0 s that way, 0.7 s compiled the first
    time and 0.06 s after; the two agree to ~1e-15, the thin film's to ~1e-10)."""
    jitted = _COMPILED.get(m.name)
    if jitted is None or jitted[0] is not m:  # a model registered again: its own
        jitted = _COMPILED[m.name] = (m, jax.jit(m))
    return jitted[1]


_COMPILED: dict[str, tuple] = {}


def _rendered(components: list[Component]) -> np.ndarray:
    """``render_values``, kept for the last few truths: noisy copies of one truth (an
    uncertainty check fits 16 to 50) render it once; ~0.3 s of the ~0.5 s a table
    takes. Read-only: every table is a new array made from it."""
    try:  # the params as given (the model checks them), arrays as lists
        key = json.dumps([[c.model, {k: v.tolist() if isinstance(v, np.ndarray) else v
                                     for k, v in sorted(c.params.items())}]
                          for c in components])
    except TypeError:  # not plain JSON: rendered each time, as before
        return render_values(components)
    return _rendered_by_key(key)


@functools.lru_cache(maxsize=2)  # a table's values are 35 MB
def _rendered_by_key(key: str) -> np.ndarray:
    values = render_values([Component(model, params) for model, params in json.loads(key)])
    values.flags.writeable = False
    return values


def make_table(
    model: str | list[Component],
    params: dict | None = None,
    *,
    noise: float = 0.0,
    missing: float = 0.0,
    keep: np.ndarray | None = None,
    seed: int = 0,
    source: str = "<synthetic>",
) -> tuple[merl.MerlTable, dict]:
    """A synthetic table and the truth that made it (JSON-ready dict)."""
    if isinstance(model, str):
        components = [Component(model, {**DEFAULT_PARAMS.get(model, {}), **(params or {})})]
    else:
        components = list(model)
    if not 0 <= noise < 10 or not 0 <= missing < 1:
        raise ValueError("noise must be in [0, 10) and missing in [0, 1)")
    values = _rendered(components)
    g = bin_grid()
    mask = g.above_horizon.copy()
    rng = np.random.default_rng(seed)
    if noise > 0:
        values = values * np.maximum(0.0, 1.0 + noise * rng.standard_normal(values.shape))
    if missing > 0:
        mask &= rng.random(mask.size) >= missing
    if keep is not None:
        mask &= np.asarray(keep, dtype=bool).ravel()
    table = merl.MerlTable.from_values(values, mask, source=source)
    truth = {
        "model": components[0].model
        if len(components) == 1
        else "+".join(c.model for c in components),
        "params": _plain(components[0].params) if len(components) == 1 else None,
        "components": [{"model": c.model, "params": _plain(c.params)} for c in components],
        "noise": noise,
        "missing": missing,
        "seed": seed,
        "measured_bins": table.n_measured,
    }
    return table, truth


def _plain(params: dict) -> dict:
    return {k: (np.asarray(v, float).tolist()) for k, v in params.items()}


def _grazing_keep() -> np.ndarray:
    g = bin_grid()
    return (g.cos_i < 0.35) | (g.cos_o < 0.35)


#: Named hard cases: (components, make_table keyword arguments).
PRESETS: dict[str, tuple[list[Component], dict]] = {
    "near-mirror": (
        [
            Component(
                "ggx", {"kd": [0.02, 0.02, 0.02], "ks": [1.0, 1.0, 1.0], "alpha": 0.01, "f0": 0.9}
            )
        ],
        {},
    ),
    "pure-diffuse": (
        [Component("ggx", {"kd": [0.6, 0.4, 0.3], "ks": [0.0, 0.0, 0.0], "alpha": 0.2, "f0": 0.5})],
        {},
    ),
    "strong-fresnel": (
        [
            Component(
                "ggx", {"kd": [0.1, 0.1, 0.1], "ks": [1.0, 1.0, 1.0], "alpha": 0.1, "f0": 0.02}
            )
        ],
        {},
    ),
    "two-lobes": (
        [
            Component(
                "ggx", {"kd": [0.1, 0.08, 0.05], "ks": [0.5, 0.5, 0.5], "alpha": 0.03, "f0": 1.0}
            ),
            Component(
                "ggx", {"kd": [0.0, 0.0, 0.0], "ks": [0.4, 0.4, 0.4], "alpha": 0.3, "f0": 1.0}
            ),
        ],
        {},
    ),
    "grazing-heavy": (
        [
            Component(
                "ggx", {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.8, 0.8], "alpha": 0.15, "f0": 0.2}
            )
        ],
        {"keep": "grazing"},
    ),
    "noisy-missing": (
        [
            Component(
                "ggx", {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.8, 0.8], "alpha": 0.15, "f0": 0.6}
            )
        ],
        {"noise": 0.2, "missing": 0.5},
    ),
    "sharp-phong": (
        [Component("phong", {"kd": [0.1, 0.1, 0.1], "ks": [0.5, 0.5, 0.5], "n": 1e4})],
        {},
    ),
}


def make_preset(
    name: str,
    seed: int = 0,
    *,
    noise: float | None = None,
    missing: float | None = None,
    params: dict | None = None,
) -> tuple[merl.MerlTable, dict]:
    """The hard case ``name``; ``noise``, ``missing`` and ``params`` given here replace
    the preset's own (``params`` only for a one-component preset: which lobe a
    parameter of a two-lobe table belongs to would be a guess)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    components, kw = PRESETS[name]
    kw = dict(kw)
    if kw.get("keep") == "grazing":
        kw["keep"] = _grazing_keep()
    for key, value in (("noise", noise), ("missing", missing)):
        if value is not None:
            kw[key] = value
    if params:
        if len(components) != 1:
            raise ValueError(
                f"preset {name!r} has {len(components)} components: --param cannot say "
                f"which one it sets; use --model {components[0].model} with --param instead")
        c = components[0]
        components = [Component(c.model, {**c.params, **params})]
    table, truth = make_table(components, seed=seed, source=f"<preset {name}>", **kw)
    truth["preset"] = name
    return table, truth


def write_table(path: str, table: merl.MerlTable, truth: dict) -> str:
    """Write the table and its ``<path>.json`` sidecar; returns the sidecar path."""
    merl.write(path, table)
    sidecar = os.fspath(path) + ".json"
    with open(sidecar, "w") as f:
        jsonout.dump(truth, f, indent=2)
    return sidecar
