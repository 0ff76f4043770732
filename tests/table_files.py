"""Synthetic MERL table files for the tests that need files on disk (batch, cluster)."""

from __future__ import annotations

from pathlib import Path


def write_tables(directory: Path, spec: dict) -> Path:
    """``directory/<name>.binary`` for each ``name: (model, params)`` of ``spec``, each
    with its truth beside it (``data_synth``); returns ``directory``."""
    from data_synth import make_table
    from data_synth.synth import write_table

    for name, (model, params) in spec.items():
        table, truth = make_table(model, params, source=name)
        write_table(str(directory / f"{name}.binary"), table, truth)
    return directory
