"""MATLAB ``.mat`` files of version 5: what ``save`` writes by default (and ``-v7``,
compressed), read through ``scipy.io`` (JAX's own dependency).

``save -v7.3`` writes HDF5, which :func:`brdffit.io.readers.read_hdf5` reads. A
version-5 file is MATLAB's own container of variables. :func:`as_hdf5` writes its
variables to an HDF5 file in memory, laid out as ``save -v7.3`` would lay them out
(column-major, each with its ``MATLAB_class``), so that the one HDF5 sample reader
reads every ``.mat`` file and says the same of the same variables: a sample list's
names, units in the names, shapes, sizes.

What the file declares (each variable's class and dimensions, from its headers) is
weighed before a number is read: a compressed file of a few MB may hold GBs.
"""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from brdffit.io.measurements import MeasurementsError

#: The first bytes of a version-5 (and -v7) MAT-file: its 116-byte text header's start.
V5_MAGIC = b"MATLAB 5.0 MAT-file"
#: MATLAB classes of numbers, as ``whos`` names them: written to HDF5 as datasets.
NUMERIC_CLASSES = frozenset({"double", "single", "int8", "uint8", "int16", "uint16",
                             "int32", "uint32", "int64", "uint64", "logical", "sparse"})
#: Classes written as HDF5 groups (so the sample reader can name them): ``-v7.3``
#: stores a struct as a group too.
GROUP_CLASSES = frozenset({"struct", "cell", "object"})

_files = itertools.count()  # names of the in-memory files, unique within the process


def is_v5(head: bytes) -> bool:
    """Whether a file's first bytes are a version-5 MAT-file's."""
    return head.startswith(V5_MAGIC)


def _declared(path: Path, source: str) -> list[tuple[str, tuple, str]]:
    """(name, MATLAB dimensions, class) of every variable, read from their headers."""
    from scipy import io

    try:
        return [(name, tuple(int(k) for k in shape), cls)
                for name, shape, cls in io.whosmat(str(path))]
    except MemoryError:
        raise MeasurementsError(source, "a MATLAB .mat file whose variables do not fit in "
                                        "memory") from None
    except Exception as e:  # noqa: BLE001 - scipy's reader raises many kinds on a damaged file
        raise MeasurementsError(source, f"not a readable MATLAB .mat file ({_said(e)})") from None


def _said(e: Exception) -> str:
    return " ".join(str(e).split())[:200] or type(e).__name__


@contextlib.contextmanager
def as_hdf5(path: str | Path, source: str, *, max_numbers: int,
            values: bool = True) -> Iterator:
    """The version-5 MAT-file ``path`` as an open HDF5 file in memory, each variable
    of numbers a dataset as ``save -v7.3`` stores it (an n x 3 matrix as (3, n), with
    its ``MATLAB_class``); a struct, cell or object an empty group (named, not read);
    text (``char``) left out, as a note. ``values=False``: the datasets declared, of
    their shapes, and nothing read (for a look at what the file declares). A variable
    of more than ``max_numbers`` numbers is refused before any is read."""
    import h5py

    declared = _declared(Path(path), source)
    numeric = [(name, shape, cls) for name, shape, cls in declared if cls in NUMERIC_CLASSES]
    for name, shape, _ in numeric:
        if int(np.prod(shape, dtype=object)) > max_numbers:
            raise MeasurementsError(source, f"variable {name} is {_dims(shape)}: more numbers "
                                            f"than a sample list read here ({max_numbers:,}); "
                                            "bin or thin it first")
    read = _loaded(Path(path), source, [n for n, _, _ in numeric]) if values and numeric else {}
    f = h5py.File(f"brdffit-mat-{next(_files)}.h5", "w", driver="core", backing_store=False)
    try:
        for name, shape, cls in declared:
            if cls in GROUP_CLASSES:
                f.create_group(name).attrs["MATLAB_class"] = np.bytes_(cls)
            elif cls in NUMERIC_CLASSES:
                if values:
                    a = read[name]
                    a = a.toarray() if hasattr(a, "toarray") else np.asarray(a)  # sparse
                    d = f.create_dataset(name, data=a.T)
                else:  # declared only: HDF5 allocates a contiguous dataset when written
                    d = f.create_dataset(name, shape=shape[::-1], dtype="f8")
                d.attrs["MATLAB_class"] = np.bytes_(cls)
        yield f
    finally:
        f.close()


def _loaded(path: Path, source: str, names: list[str]) -> dict:
    from scipy import io

    try:
        return io.loadmat(str(path), variable_names=names, squeeze_me=False,
                          chars_as_strings=True)
    except MemoryError:
        raise MeasurementsError(source, "a MATLAB .mat file whose variables do not fit in "
                                        "memory") from None
    except Exception as e:  # noqa: BLE001 - scipy's reader raises many kinds on a damaged file
        raise MeasurementsError(source, f"a MATLAB .mat file whose variables cannot be read "
                                        f"({_said(e)})") from None


def _dims(shape: tuple) -> str:
    """MATLAB's way of writing a size: 3 x 1000."""
    return " x ".join(str(k) for k in shape)
