"""What models there are, without JAX: names, aliases, ``auto`` and parameters.

Everything that only needs to *name* or *describe* a model reads this module:
``brdffit models``, the service's ``/v1/models``, and the option checks of the
CLI, the service and the batch job. It imports no JAX, so those answer in a
fraction of a second; fitting goes through :mod:`brdffit.models.registry`.

The built-in models' descriptions are a snapshot of the registry kept beside
this file (``catalogue.json``, package data). A test compares it with the live
registry; after changing a model run ``python -m brdffit.models --write-catalogue``.
Models from other packages (the ``brdffit.models`` entry-point group, see
docs/adding-a-model.md) are described by importing them.
"""

from __future__ import annotations

import functools
import json
import sys
from importlib.metadata import entry_points
from pathlib import Path

from brdffit.errors import BrdffitError

SNAPSHOT = Path(__file__).with_name("catalogue.json")
#: The entry-point group through which other packages add models.
ENTRY_POINT_GROUP = "brdffit.models"
#: Not a model: "fit the candidates and choose" (``brdffit.selection``).
AUTO = "auto"
#: ``"ggx_mono"``: a registered model with one grey specular scale (models/mono_ks.py).
MONO_SUFFIX = "_mono"


class UnknownModelError(BrdffitError, KeyError):
    """A model name that is not in the registry (a KeyError for mapping-style callers)."""

    def __str__(self) -> str:  # KeyError quotes its message otherwise
        return self.args[0]


@functools.cache
def _builtin() -> tuple[dict, ...]:
    return tuple(json.loads(SNAPSHOT.read_text()))


@functools.cache
def plugin_names() -> tuple[str, ...]:
    """Names of the models other packages declare (not imported)."""
    return tuple(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))


def load_plugins() -> list:
    """The model objects other packages declare (``name = "package.module:Model"``,
    a class or an instance), imported now."""
    out = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        obj = ep.load()
        model = obj() if isinstance(obj, type) else obj
        if model.name != ep.name:
            raise ValueError(f"entry point {ep.name!r} names a model called {model.name!r}")
        out.append(model)
    return out


#: Descriptions of models registered in this process (``registry.register``
#: adds them), beyond the built-ins and the plugins.
_REGISTERED: dict[str, dict] = {}


def add(model) -> None:
    """Describe ``model`` from now on (called by ``brdffit.models.registry.register``)."""
    _REGISTERED[model.name] = describe_model(model)


def describe() -> list[dict]:
    """Every registered model as plain data, cheapest first (``brdffit models --json``)."""
    known = list(_builtin())
    seen = {m["name"] for m in known}
    if set(plugin_names()) - seen - set(_REGISTERED):  # described by importing them
        for model in load_plugins():
            _REGISTERED.setdefault(model.name, describe_model(model))
    known += [d for name, d in _REGISTERED.items() if name not in seen]
    return known


#: Candidate sets by the renderer a material is for: ``auto`` among the materials
#: that renderer's file carries, layers included (``--candidates gltf``; a set's name
#: stands for its models, in the registry's order). A layered model is fitted from
#: its base's fit and chosen only where its layer gains what the rule asks. glTF's thin
#: film (``gltf_iridescence``) is tried where named: its fit refines 4 starts over a scan
#: of films (4-12 s on a real table, median 5.5 s, against gltf_pbr's 0.2 s), and on the MERL
#: colour-changing paints it gained under 1% of log_rmse (docs/models.md).
CANDIDATE_SETS: dict[str, tuple[str, ...]] = {
    "gltf": ("gltf_pbr", "gltf_clearcoat", "gltf_sheen"),
    # lambert: Mitsuba's own diffuse plugin, exported exactly (a matte table's cheapest)
    "mitsuba": ("lambert", "rough_conductor", "rough_plastic", "principled",
                "principled_clearcoat"),
    # generalized_schlick: a highlight whose colour turns with the angle (effect paints)
    "materialx": ("standard_surface_dielectric", "standard_surface", "standard_surface_coat",
                  "standard_surface_sheen", "generalized_schlick"),
}


#: a word among the candidates for auto's own default list: the lobe models that are not
#: defaults (ggx3, ggx4) or a plugin's model are added to it without spelling it out
DEFAULT_CANDIDATES = "default"


def expand_candidates(names) -> tuple:
    """``names`` with each :data:`CANDIDATE_SETS` name, and ``default``
    (:func:`auto_candidates`), replaced by those of its models not named before it (a
    name given twice stays twice: the caller decides)."""
    out: list = []
    for name in names:
        if isinstance(name, str) and (name in CANDIDATE_SETS or name == DEFAULT_CANDIDATES):
            members = (auto_candidates() if name == DEFAULT_CANDIDATES
                       else CANDIDATE_SETS[name])
            out += [m for m in members if m not in out]
        else:
            out.append(name)
    return tuple(out)


def auto_candidates() -> tuple[str, ...]:
    """The models ``model="auto"`` tries by default, cheapest first: every model of the
    catalogue that declares itself one (``auto_candidate``), in the registry's order;
    a plugin model may declare itself one too."""
    return tuple(d["name"] for d in describe() if d.get("auto"))


def names() -> list[str]:
    """The registered model names, cheapest first."""
    return [m["name"] for m in describe()]


def check_name(name: str, allow_auto: bool = False) -> str:
    """``name`` if it names a model (or ``auto`` where allowed), else UnknownModelError
    with the choices; the one check behind every shell's model option."""
    if allow_auto and name == AUTO:
        return name
    info = {m["name"]: m for m in describe()}
    if name in info:
        return name
    base = info.get(name.removesuffix(MONO_SUFFIX)) if name.endswith(MONO_SUFFIX) else None
    if base is not None and base["mono"]:
        return name
    choices = ", ".join(info) + (f", or {AUTO}" if allow_auto else "")
    raise UnknownModelError(f"unknown model {_quoted(name)}; choose one of {choices} "
                            f"(or a model with a grey ks: NAME{MONO_SUFFIX}, where "
                            "`brdffit models` lists one)")


#: A name longer than this is quoted cut short in a refusal: the list of choices
#: after it is what the reader needs (a 900,000-character name was quoted whole).
QUOTED_NAME_CHARS = 60


def _quoted(name) -> str:
    text = repr(name)
    if len(text) <= QUOTED_NAME_CHARS:
        return text
    return f"{text[:QUOTED_NAME_CHARS]}... ({len(str(name)):,} characters)"


def n_params(name: str) -> int:
    """How many numbers model ``name`` (a ``_mono`` variant too) fits, from its
    description; UnknownModelError for a name that is not a model."""
    info = {m["name"]: m for m in describe()}
    if name in info:
        return info[name]["n_params"]
    check_name(name)  # a `_mono` variant, or UnknownModelError
    return info[name.removesuffix(MONO_SUFFIX)]["mono_n_params"]


def describe_model(model) -> dict:
    """One model instance as plain data (the snapshot's and the API's shape)."""
    from brdffit.models.mono_ks import MonoKs, specular_colour_specs

    doc = sys.modules[type(model).__module__].__doc__ or model.name
    greyed = [s.name for s in specular_colour_specs(model)]
    mono = bool(greyed)  # it has a `_mono` variant
    return {
        "name": model.name,
        # the module docstring's first line (the formula), without its reST literals' marks
        "doc": doc.strip().splitlines()[0].replace("``", ""),
        "params": [
            {"name": s.name, "size": s.size, "range": s.describe_range(),
             "lower": s.lower, "upper": s.upper, "doc": s.doc,
             # the range of a physically bounded fit (brdffit.fitting.physical)
             "physical_upper": phys.upper}
            for s, phys in zip(model.param_specs, model.physical_specs, strict=True)
        ],
        "n_params": model.n_params,
        "parent": model.parent,
        "mono": mono,
        "mono_n_params": MonoKs(model).n_params if mono else None,
        "mono_params": greyed,  # what its `_mono` variant makes one grey value
        "auto": bool(getattr(model, "auto_candidate", False)),
        # the fewest starts its fit refines, whatever is asked (a thin film's many modes)
        "least_starts": int(getattr(model, "least_starts", 1)),
    }


def snapshot(builtin) -> str:
    """The descriptions of ``builtin`` (the registry's built-in models) as the
    snapshot file holds them."""
    return json.dumps([describe_model(m) for m in builtin], indent=1) + "\n"
