"""Exports from a batch results file (brdffit.batch.exports.export_from_store and
brdffit.batch.store.read_fit): a fit found by the table's name, path or file name, the
best fit by default, and errors that say what the file holds."""

from __future__ import annotations

import os

import h5py
import numpy as np
import pytest

from brdffit import merl, models
from brdffit.batch.exports import export_from_store
from brdffit.batch.job import run_batch
from brdffit.batch.store import BatchFileError, read_fit, read_results, table_name
from brdffit.export import ExportError, export
from brdffit.fitting.result import FitResult
from brdffit.io.grid import bin_grid
from brdffit.request import FitRequest
from brdffit.selection import TIE
from data_synth import make_table

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """Two tables both called gold.binary (in a/ and b/), and one of 8 measured bins,
    too few for any fit."""
    root = tmp_path_factory.mktemp("store")
    keep = np.zeros(bin_grid().above_horizon.size, bool)
    keep[np.flatnonzero(bin_grid().above_horizon)[::100_000][:8]] = True
    tables = {
        "a/gold.binary": make_table("ggx", {"kd": [0.05, 0.04, 0.02], "ks": [0.6, 0.4, 0.2],
                                            "alpha": 0.2, "f0": 1.0})[0],
        "b/gold.binary": make_table("lambert", {"kd": [0.5, 0.4, 0.3]})[0],
        "sparse.binary": make_table("lambert", {"kd": [0.5, 0.4, 0.3]}, keep=keep)[0],
    }
    for rel, table in tables.items():
        (root / rel).parent.mkdir(exist_ok=True)
        merl.write(root / rel, table)
    out = root / "results.h5"
    run_batch([str(root / rel) for rel in tables], FitRequest.of(["ggx", "lambert"], samples=1024),
              out, workers=0, progress=False)
    return root, out


def _stored(out, name: str, model: str) -> FitResult:
    table = next(t for t in read_results(out)["tables"] if t["name"] == name)
    return FitResult.from_dict(table["fits"][model]["fit"])


def test_two_tables_of_one_file_name_export_to_files_of_their_own(store):
    """a/gold.binary and b/gold.binary are gold and gold~2 in the file: their exports
    are named so (both were gold_lambert.*, the second overwriting the first)."""
    _, out = store
    first = export_from_store(out, "gold", "mitsuba", model="lambert")
    second = export_from_store(out, "gold~2", "mitsuba", model="lambert")
    assert "gold_lambert.xml" in first.files and "gold~2_lambert.xml" in second.files
    assert set(first.files).isdisjoint(second.files)


@pytest.mark.slow
def test_a_stored_fit_exports_as_the_fit_itself(store):
    root, out = store
    want = export(_stored(out, "gold", "ggx"), "gltf")
    got = export_from_store(out, "gold", "gltf", model="ggx")
    assert got.to_dict() == want.to_dict()
    # by its path: the same fit, and the same name (what export_from_store exports)
    by_path = str(root / "a" / "gold.binary")
    assert read_fit(out, by_path, "ggx") == _stored(out, "gold", "ggx").to_dict()
    assert table_name(out, by_path) == "gold"
    assert read_fit(out, "gold~2", "lambert") == _stored(out, "gold~2", "lambert").to_dict()


def test_the_default_is_the_best_fit(store):
    _, out = store
    fits = {m: _stored(out, "gold~2", m) for m in ("ggx", "lambert")}
    lowest = min(r.log_rmse for r in fits.values())
    # the lowest log_rmse; a tie (ggx on a lambert table, ks -> 0) to fewer parameters
    tied = [m for m, r in fits.items() if r.log_rmse <= lowest + TIE]
    best = min(tied, key=lambda m: models.get(m).n_params)
    assert read_fit(out, "gold~2")["model"] == best


def test_a_table_named_by_the_relative_path_the_batch_was_given(store, monkeypatch):
    """--table btab/chrome-steel.binary, as the batch was run, was "no table": the file
    holds the absolute path."""
    root, out = store
    monkeypatch.chdir(root)
    assert read_fit(out, os.path.join("a", "gold.binary"), "lambert") == \
        _stored(out, "gold", "lambert").to_dict()


def test_unknown_table_or_model_lists_what_the_file_holds(store):
    root, out = store
    with pytest.raises(BatchFileError, match=r"no table 'silver'; the file holds gold, gold~2, "
                                             r"sparse"):
        read_fit(out, "silver", "ggx")
    with pytest.raises(BatchFileError, match=r"'gold.binary' names several tables: gold, gold~2"):
        read_fit(out, "gold.binary", "ggx")
    with pytest.raises(BatchFileError, match="table 'gold' has no beckmann fit; it has ggx, "
                                             "lambert"):
        export_from_store(out, "gold", "mitsuba", model="beckmann")


def test_a_failed_fit_says_why(store):
    _, out = store
    with pytest.raises(BatchFileError, match="the ggx fit of table 'sparse' failed: .*only 8 "
                                             "usable bins"):
        read_fit(out, "sparse", "ggx")
    with pytest.raises(BatchFileError, match="table 'sparse' has no successful fit; its fits: "
                                             "ggx .*, lambert "):
        read_fit(out, "sparse")


def test_a_table_that_failed_to_read_says_why(store, tmp_path):
    """A table the batch could not read has a group with its reason and no fits: an
    export of it says that reason (it said only 'has no successful fit')."""
    import shutil

    _, out = store
    copy = tmp_path / "r.h5"
    shutil.copy(out, copy)
    with h5py.File(copy, "a") as f:  # as the batch records a failed read (tasks.read_table)
        g = f["tables"].create_group("lost")
        g.attrs.update({"status": "failed", "path": "/x/lost.binary",
                        "message": "/x/lost.binary: cannot read: No such file or directory"})
    for model in (None, "ggx"):
        with pytest.raises(BatchFileError, match="table 'lost' was not fitted: /x/lost.binary: "
                                                 "cannot read: No such file"):
            read_fit(copy, "lost", model)


def test_not_a_batch_file_and_a_bad_target_are_clear_errors(store, tmp_path):
    _, out = store
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = 1
    with pytest.raises(BatchFileError, match="not a brdffit batch results file"):
        export_from_store(other, "gold", "gltf")
    with pytest.raises(ExportError, match="unknown export target 'blender'"):
        export_from_store(out, "gold", "blender")
