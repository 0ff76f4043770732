"""Tables in the service's store: validated once, stored by content, shared by the
upload route (``/v1/tables``) and the shipped materials (``/v1/materials``)."""

from __future__ import annotations

import hashlib
import tempfile
from pathlib import Path

from api.store import Store, TableRecord
from brdffit.io import merl, readers
from brdffit.io.measurements import Measurements
from brdffit.io.writers import write_hdf5


def validate_and_store(store: Store, tmp: Path, digest: str, size: int,
                       name: str) -> tuple[TableRecord, bool]:
    """Store the table file ``tmp`` (its ``sha256`` and ``size`` already known) under
    ``name``: ``(record, created)``, ``created`` False where the same bytes were stored
    before. A file of samples (ASTM, CSV, HDF5; ``brdffit.io.readers``, chosen by
    ``name``'s suffix or the content) is stored as brdffit's HDF5 sample list (read
    back by its content whatever the stored file is called), which the jobs fit at its
    own directions; its summary is the summary of the table it bins into (what the
    plots draw), with ``input`` saying what the binning did. The id stays the
    upload's sha256. Raises ``MerlFormatError`` naming ``name`` (not the temp file) for
    a file no reader takes."""
    record = store.get_table(digest)
    if record is not None:  # known bytes: already validated
        tmp.unlink(missing_ok=True)
        return record, False
    measured = readers.read_measured(tmp, name=name)  # errors name the upload
    if isinstance(measured, Measurements):
        write_hdf5(measured, tmp)  # one layout for the jobs to read, sigma and all
        size = tmp.stat().st_size
    return store.add_table(digest, tmp, size, name, readers.table_summary(measured))



def nbrdf():
    """``data_synth.nbrdf`` where this installation has it, else None."""
    try:
        from data_synth import nbrdf as module
    except ImportError:  # an installation of brdffit and api alone
        return None
    return module


def material_names() -> list[str] | None:
    """The shipped real materials, or None where this installation has none."""
    module = nbrdf()
    return None if module is None else list(module.material_names())


def store_material(store: Store, name: str) -> tuple[TableRecord, bool]:
    """Rebuild the shipped material ``name`` (a known one: see :func:`material_names`)
    and store it as a table, as an upload of its bytes would be."""
    fd, tmp = tempfile.mkstemp(prefix="material-", suffix=".binary", dir=store.tmp_dir)
    path = Path(tmp)
    try:
        with open(fd, "wb") as f:
            f.write(merl.to_bytes(nbrdf().make_table(name)))
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        return validate_and_store(store, path, digest, path.stat().st_size, f"{name}.binary")
    finally:
        path.unlink(missing_ok=True)
