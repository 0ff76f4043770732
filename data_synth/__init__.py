"""Synthetic MERL tables with known parameters, noise, missing bins and hard cases.

    from data_synth import make_table, PRESETS
    table, truth = make_table("ggx", {"kd": [.1, .2, .3], "ks": 1, "alpha": .2, "f0": .9})

``python -m data_synth --help`` writes them to disk with a JSON sidecar of the truth.
"""

from data_synth.synth import (
    DEFAULT_PARAMS,
    PRESETS,
    Component,
    make_table,
    render_values,
    write_table,
)

__all__ = ["DEFAULT_PARAMS", "PRESETS", "Component", "make_table", "render_values", "write_table"]
