"""A fit in a batch results file as a renderer's material: :func:`export_from_store`.

The batch store (``brdffit.batch.store``) holds each fit in the result schema; this
reads one back and hands it to ``brdffit.export.export``, so that a batch's fits
export exactly as a single fit's do.
"""

from __future__ import annotations

from brdffit.batch.store import read_fit, table_name
from brdffit.export import TARGETS, Export, ExportError, export
from brdffit.fitting.result import FitResult


def export_from_store(store: str, table: str, target: str, model: str | None = None, *,
                      table_file=None, target_model: str | None = None,
                      viewer: str = "spec") -> Export:
    """The ``model`` fit (None: the best) of ``table`` in the batch results file
    ``store`` (``brdffit batch``) as a material of ``target``: ``brdffit.export.export``
    of :func:`brdffit.batch.store.read_fit`'s result. ``table`` is the table's name in
    the file, its path or its file name; an unknown one is an error that lists what the
    file holds. ``table_file``, ``target_model``, ``viewer``: as ``export``'s ``table``,
    ``target_model`` and ``viewer``."""
    if target not in TARGETS:  # before the file is opened
        raise ExportError(f"unknown export target {target!r}; choose one of {', '.join(TARGETS)}")
    fitted = FitResult.from_dict(read_fit(store, table, model))
    # named by the table's name in the file: two tables whose files share a name
    # (a/mat.binary, b/mat.binary: mat, mat~2) would write the same files
    return export(fitted, target, table=table_file, target_model=target_model, viewer=viewer,
                  name=f"{table_name(store, table)}_{fitted.model}")
