"""Files of named arrays, a MATLAB file's variables or an ``.npz`` archive's arrays,
given to the HDF5 sample reader as an HDF5 file in memory (:mod:`brdffit.io.matlab`,
:mod:`brdffit.io.npz`): what such a file declares is checked here, before a dataset is
made or a number read.

Every variable is first declared, a dataset of its shape that HDF5 does not allocate
(the sample reader names them, and refuses an uncertainty or a channel index by its
name), and what the file declares is weighed; then only those the reader reads
(``wanted``) are filled with their values: a file of a few KB may declare GBs in
variables no fit needs (a 23 KB .mat of empty sparse matrices took 4.9 GB when every
variable was read).
"""

from __future__ import annotations

import itertools

import numpy as np

from brdffit.io.measurements import MeasurementsError

#: The most variables one file may hold: a sample list has a handful; a MATLAB
#: workspace saved whole, hundreds. (160,000 empty ones took a minute to read.)
MAX_VARIABLES = 1000
_files = itertools.count()  # names of the in-memory files, unique within the process


def checked(declared: list[tuple[str, tuple]], source: str, *, noun: str, file: str,
            max_numbers: int, wanted) -> None:
    """Refuses, with one line, a file whose ``declared`` (name, shape) pairs no HDF5
    file can hold, or that would read too much: more than :data:`MAX_VARIABLES`, a name
    twice, a name HDF5 cannot take (empty, ``.``, with ``/`` or NUL; MATLAB writes none
    of them), a negative dimension, or a variable the reader reads (``wanted(name)``)
    of more than ``max_numbers`` numbers."""
    if len(declared) > MAX_VARIABLES:
        raise MeasurementsError(source, f"{len(declared):,} {noun}s: more than a sample list "
                                        f"holds ({MAX_VARIABLES:,} are read); save the "
                                        f"angles and values alone")
    seen: set[str] = set()
    for name, shape in declared:
        if not name or name in (".", "..") or "/" in name or "\x00" in name:
            raise MeasurementsError(source, f"not a readable {file} (a {noun} named "
                                            f"{name!r})")
        if name in seen:
            raise MeasurementsError(source, f"not a readable {file} ({noun} {name} appears "
                                            "twice)")
        seen.add(name)
        if any(k < 0 for k in shape):
            raise MeasurementsError(source, f"not a readable {file} ({noun} {name} declares "
                                            f"dimensions {list(shape)})")
        numbers = int(np.prod(shape, dtype=object))
        if wanted(name) and numbers > max_numbers:
            raise MeasurementsError(source, f"{noun} {name} holds {numbers:,} numbers: more "
                                            f"than a sample list read here ({max_numbers:,}); "
                                            "bin or thin it first")


def in_memory(kind: str):
    """A new, empty HDF5 file in memory (never written to disk)."""
    import h5py

    return h5py.File(f"brdffit-{kind}-{next(_files)}.h5", "w", driver="core",
                     backing_store=False)


def declare(f, name: str, shape: tuple):
    """Dataset ``name`` of ``shape`` (float64), its values never written: HDF5 keeps
    no storage for it."""
    return f.create_dataset(name, shape=shape, dtype="f8")


def fill(f, name: str, data) -> None:
    """Declared dataset ``name`` given its values (made again: a dataset's type and
    storage are fixed when it is made), its attributes kept."""
    attrs = dict(f[name].attrs)
    del f[name]
    f.create_dataset(name, data=data).attrs.update(attrs)


#: The most characters of one text read (a long layout's channel names: ``r``, ``450nm``).
MAX_TEXT = 256


def fill_text(f, name: str, texts) -> None:
    """Dataset ``name`` made a dataset of text, one string per element of ``texts``, of
    its shape (a long layout's channel names; bytes as UTF-8, a NUL shown as ``\\x00``: HDF5's
    strings hold none), its attributes kept."""
    import h5py

    def text(t) -> str:
        t = t.decode("utf-8", "replace") if isinstance(t, bytes) else str(t)
        return t.replace("\x00", "\\x00")

    attrs = dict(f[name].attrs)
    del f[name]
    data = np.array([text(t) for t in np.ravel(texts)], dtype=object).reshape(np.shape(texts))
    f.create_dataset(name, data=data, dtype=h5py.string_dtype()).attrs.update(attrs)


def not_numbers(dtype: np.dtype) -> str | None:
    """What an array of ``dtype`` holds where that is not real numbers, as a refusal
    says it ("dataset rgb holds booleans (a mask?), not numbers"); None for integers
    and floats. Dates and durations (``datetime64[s]``) by their type: numpy's, which
    HDF5 has none of (an .npz of them crashed the reader with h5py's TypeError)."""
    kind = dtype.kind
    if kind in "iuf":
        return None
    if kind in "SUO":
        return "text"
    if kind == "c":
        return "complex numbers (a BRDF is real: keep the real part)"
    if kind == "b":
        return "booleans (a mask?)"
    if kind == "V" and dtype.names:
        return f"records of fields {', '.join(dtype.names[:8])}"
    if kind == "V":
        return f"raw bytes ({dtype})"
    return str(dtype)  # datetime64[s], timedelta64[ms]


def said(e: Exception) -> str:
    """A reader library's exception in one line, for a refusal's parentheses."""
    return " ".join(str(e).split())[:200] or type(e).__name__
