"""Synthetic MERL tables with known parameters, noise, missing bins and hard cases.

    from data_synth import make_table, PRESETS
    table, truth = make_table("ggx", {"kd": [.1, .2, .3], "ks": 1, "alpha": .2, "f0": .9})

``python -m data_synth --help`` writes them to disk with a JSON sidecar of the truth.
"""

__all__ = ["DEFAULT_PARAMS", "PRESETS", "Component", "make_table", "render_values", "write_table"]


def __getattr__(name: str):
    # data_synth.synth (JAX) is imported on first use of its names, not with the
    # package: the service's front lists and stores the shipped materials
    # (data_synth.nbrdf, numpy alone) and loads no JAX (docs/service.md)
    if name in __all__:
        from data_synth import synth

        return getattr(synth, name)
    raise AttributeError(f"module 'data_synth' has no attribute {name!r}")
