"""NumPy ``.npz`` archives of named arrays (``np.savez``, ``np.savez_compressed``), read
as an HDF5 file of the same datasets is.

``np.savez("s.npz", theta_i_deg=..., phi_i_deg=..., theta_o_deg=..., phi_o_deg=...,
rgb=...)`` is how a Python user keeps a sample list. :func:`as_hdf5` writes its arrays
to an HDF5 file in memory, each a dataset of its name, so that the one HDF5 sample
reader (:func:`brdffit.io.named_arrays.read_hdf5`'s) reads them and says the same of them:
names, units in the names, shapes, sizes. numpy stores row-major, as HDF5 does: an
(n, 3) ``rgb`` is (n, 3).

Each array's shape and type are read from its own header, before a number is read:
a compressed archive of a few KB may declare GBs. An array of Python objects
(pickled) is refused, never unpickled: a file may be an upload.
"""

from __future__ import annotations

import contextlib
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from brdffit.io import merl, variables
from brdffit.io.measurements import MeasurementsError

#: A zip archive's first bytes: an .npz file is one, of .npy members.
ZIP_MAGIC = b"PK\x03\x04"


def zip_members(path: str | Path) -> list[str] | None:
    """The member names of the zip archive ``path``, or None where it is not one."""
    try:
        with zipfile.ZipFile(path) as z:
            return z.namelist()
    except (OSError, zipfile.BadZipFile, ValueError):
        return None


def is_npz(path: str | Path) -> bool:
    """Whether ``path`` is a zip archive whose members are all ``.npy`` arrays (an
    Excel workbook is a zip archive too)."""
    names = zip_members(path)
    return bool(names) and all(n.endswith(".npy") for n in names)


#: How a file named .npz that is none is refused (``brdffit.io.readers.reader_for``): it
#: was read as a CSV of another name, in a sample list's words ("no column for theta_i",
#: "a zip archive, not a text sample list": an .npz is one).
NOT_NPZ = "not a readable .npz (NumPy's zip of arrays)"


def not_npz(path: str | Path, head: bytes) -> str | None:
    """Why the file ``path``, of first bytes ``head``, is no .npz archive, in words for
    a file named as one; None where it is one, or an archive of no arrays (its reader
    says that)."""
    if not head:
        return "an empty file (0 bytes)"
    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
    except (OSError, zipfile.BadZipFile, ValueError) as e:
        if head.startswith(ZIP_MAGIC):
            return f"a zip archive cut short or damaged ({variables.said(e)})"
        kind = merl.other_format(head)
        hint = " (decompress it first)" if kind == "a gzip archive" else ""
        return f"{kind or 'binary data'}, not a zip archive (by its first bytes){hint}"
    others = [n for n in names if not n.endswith(".npy")]
    if not others:
        return None
    more = f" and {len(others) - 3} more" if len(others) > 3 else ""
    return f"a zip archive of other files ({', '.join(others[:3])}{more}), not of .npy arrays"


def _declared(z: zipfile.ZipFile, source: str) -> list[tuple[str, tuple, np.dtype]]:
    """(name, shape, dtype) of every array, from its .npy header alone."""
    out = []
    for member in z.namelist():
        name = member[:-len(".npy")]
        try:
            with z.open(member) as f:
                version = np.lib.format.read_magic(f)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(f)
                elif version == (2, 0):
                    shape, _, dtype = np.lib.format.read_array_header_2_0(f)
                else:
                    raise ValueError(f"an .npy of format version {version[0]}.{version[1]}")
        except Exception as e:  # noqa: BLE001 - zipfile and numpy raise many kinds on a damaged file
            raise MeasurementsError(source, f"array {name}: not a readable .npy header "
                                            f"({variables.said(e)})") from None
        if dtype.hasobject:
            raise MeasurementsError(source, f"array {name} holds Python objects (pickled), "
                                            "which are not read: save numbers")
        out.append((name, tuple(int(k) for k in shape), dtype))
    return out


@contextlib.contextmanager
def as_hdf5(path: str | Path, source: str, *, max_numbers: int, wanted=lambda name: True,
            values: bool = True, before_reading=None) -> Iterator:
    """The .npz archive ``path`` as an open HDF5 file in memory, each array a dataset
    of its name (text a dataset of text: read where it is wanted, a long layout's
    channels, else left empty and refused where it is read). Every array is
    declared first and ``before_reading(f)`` called (it may refuse the file), then only
    the arrays ``wanted(name)`` are read (:mod:`brdffit.io.variables`);
    ``values=False``: none is, for a look at what the file declares."""
    try:
        z = zipfile.ZipFile(path)
    except (OSError, zipfile.BadZipFile, ValueError) as e:
        raise MeasurementsError(source, f"not a readable .npz archive "
                                        f"({variables.said(e)})") from None
    with z:
        declared = _declared(z, source)
        variables.checked([(n, shape) for n, shape, _ in declared], source, noun="array",
                          file=".npz archive", max_numbers=max_numbers, wanted=wanted)
        f = variables.in_memory("npz")
        try:
            for name, shape, dtype in declared:
                if dtype.kind in "US":  # text (a note): not read
                    f.create_dataset(name, data=np.bytes_(b""))
                else:
                    variables.declare(f, name, shape)
            if before_reading is not None:
                before_reading(f)
            for name, _, dtype in declared:
                if not (values and wanted(name)):
                    continue
                if dtype.kind in "Mm":  # dates or durations: HDF5 holds none, so they are
                    # refused here as the reader refuses an array of booleans when it reads it
                    raise MeasurementsError(source, f"array {name} holds "
                                                    f"{variables.not_numbers(dtype)}, not numbers")
                if dtype.kind in "US":  # text the reader reads: a long layout's channels
                    if dtype.itemsize > 4 * variables.MAX_TEXT:  # before it is read
                        raise MeasurementsError(source, f"array {name} holds texts of "
                                                        f"{dtype.itemsize:,} bytes each: a "
                                                        "channel's name is short")
                    variables.fill_text(f, name, _array(z, name, source))
                else:
                    variables.fill(f, name, _array(z, name, source))
            yield f
        finally:
            f.close()


def _array(z: zipfile.ZipFile, name: str, source: str) -> np.ndarray:
    try:
        with z.open(f"{name}.npy") as member:
            return np.lib.format.read_array(member, allow_pickle=False)
    except MemoryError:
        raise MeasurementsError(source, f"array {name} does not fit in memory") from None
    except Exception as e:  # noqa: BLE001 - zipfile and numpy raise many kinds on a damaged file
        raise MeasurementsError(source, f"array {name} cannot be read "
                                        f"({variables.said(e)})") from None
