"""MATLAB ``.mat`` files of version 5: what ``save`` writes by default (and ``-v7``,
compressed), read through ``scipy.io`` (JAX's own dependency).

``save -v7.3`` writes HDF5, which :func:`brdffit.io.named_arrays.read_hdf5` reads. A
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
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from brdffit.io import variables
from brdffit.io.measurements import MeasurementsError

#: The first bytes of a version-5 (and -v7) MAT-file: its 116-byte text header's start.
V5_MAGIC = b"MATLAB 5.0 MAT-file"
#: MATLAB classes of numbers, as ``whos`` names them: written to HDF5 as datasets.
NUMERIC_CLASSES = frozenset({"double", "single", "int8", "uint8", "int16", "uint16",
                             "int32", "uint32", "int64", "uint64", "logical", "sparse"})


#: Classes a variable of text may have: a char matrix, a cell array (of strings).
TEXT_CLASSES = frozenset({"char", "cell"})


def is_v5(head: bytes) -> bool:
    """Whether a file's first bytes are a version-5 MAT-file's."""
    return head.startswith(V5_MAGIC)


def _cut_short(path: Path) -> bool:
    """Whether the file ends inside a variable: each top-level element's tag gives its
    length, and the last runs past the end (scipy's list of variables stops there
    without a word, and a cut-off upload read as "no variable phi_i")."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        header = f.read(128)
        if len(header) < 128:
            return True
        order = "<" if header[126:128] == b"IM" else ">"
        position = 128
        while position + 8 <= size:
            f.seek(position)
            _, nbytes = np.frombuffer(f.read(8), f"{order}u4")
            position += 8 + int(nbytes)  # a top-level element is never padded
        return position > size


def _declared(path: Path, source: str) -> list[tuple[str, tuple, str]]:
    """(name, MATLAB dimensions, class) of every variable, read from their headers."""
    from scipy import io

    if _cut_short(path):
        raise MeasurementsError(source, "a MATLAB .mat file cut short: its last variable "
                                        "runs past the end of the file")
    try:
        return [(name, tuple(int(k) for k in shape), cls)
                for name, shape, cls in io.whosmat(str(path))]
    except MemoryError:
        raise MeasurementsError(source, "a MATLAB .mat file whose variables do not fit in "
                                        "memory") from None
    except Exception as e:  # noqa: BLE001 - scipy's reader raises many kinds on a damaged file
        # scipy takes a version field it does not know for -v7.3 and says to use h5py,
        # which brdffit does by itself: the header is damaged
        why = "its header's version field is damaged" if "v7.3" in str(e) else variables.said(e)
        raise MeasurementsError(source, f"not a readable MATLAB .mat file ({why})") from None


@contextlib.contextmanager
def as_hdf5(path: str | Path, source: str, *, max_numbers: int, wanted=lambda name: True,
            values: bool = True, before_reading=None) -> Iterator:
    """The version-5 MAT-file ``path`` as an open HDF5 file in memory, each variable
    of numbers a dataset as ``save -v7.3`` stores it (an n x 3 matrix as (3, n), with
    its ``MATLAB_class``; a logical one of booleans); text (``char``) a dataset of text
    (read where it is wanted, a long layout's channel names, one per row; else left
    empty and refused where it is read); a struct, cell or object an empty group (named,
    not read; a wanted cell of strings is read as text). Every variable is declared
    first and ``before_reading(f)`` called (it may refuse the file), then only the
    variables ``wanted(name)`` are read (:mod:`brdffit.io.variables`); ``values=False``:
    none is, for a look at what the file declares."""
    declared = _declared(Path(path), source)
    variables.checked([(n, shape) for n, shape, _ in declared], source, noun="variable",
                      file="MATLAB .mat file", max_numbers=max_numbers, wanted=wanted)
    f = variables.in_memory("mat")
    try:
        for name, shape, cls in declared:
            if cls not in NUMERIC_CLASSES and cls != "char":  # a struct, cell, object, ...
                d = f.create_group(name)
                d.attrs["MATLAB_dims"] = np.asarray(shape, np.int64)  # what it holds
            elif cls == "char":  # its text is not read: refused as text where it is wanted
                d = f.create_dataset(name, data=np.bytes_(b""))
            else:
                d = variables.declare(f, name, shape[::-1])
            d.attrs["MATLAB_class"] = np.bytes_(cls)
        if before_reading is not None:
            before_reading(f)
        for name, shape, cls in declared:
            if cls == "char" and wanted(name) and len(shape) == 2 and shape[1] > variables.MAX_TEXT:
                raise MeasurementsError(source, f"variable {name} is a char matrix of rows of "
                                                f"{shape[1]:,} characters: a channel's name is "
                                                "short")
        if values:
            classes = {name: cls for name, _, cls in declared}
            read = _loaded(Path(path), source, [n for n, cls in classes.items()
                                                if wanted(n) and (cls in NUMERIC_CLASSES
                                                                  or cls in TEXT_CLASSES)])
            for name in read.keys() & classes.keys():
                a = read[name]
                if classes[name] in TEXT_CLASSES:  # a long layout's channel names
                    if (texts := _texts(a)) is not None:
                        variables.fill_text(f, name, texts)
                        # rows and characters (scipy's header gives the rows alone): a
                        # 1 x n char of n channels' letters is one text, not one element
                        f[name].attrs["MATLAB_dims"] = np.asarray(
                            [len(texts), max(map(len, texts), default=0)], np.int64)
                    continue
                a = a.toarray() if hasattr(a, "toarray") else np.asarray(a)  # sparse
                if classes[name] == "logical":  # scipy reads it as uint8: a mask
                    a = a.astype(bool)
                variables.fill(f, name, a.T)
        yield f
    finally:
        f.close()


def _texts(a: np.ndarray) -> list[str] | None:
    """A char matrix's rows (scipy joins each row into one string) or a cell array of
    strings (``{'r'; 'g'; 'b'}``) as a list of strings, column-major as MATLAB orders a
    cell; None for a cell of anything else (it stays a group: "a struct or cell")."""
    if a.dtype.kind == "U":
        return [t.rstrip() for t in a.ravel()]
    texts = []
    for cell in a.ravel(order="F"):
        cell = np.asarray(cell)
        if cell.dtype.kind != "U" or cell.size > 1:  # numbers, or a char matrix of rows
            return None
        texts.append(str(cell.ravel()[0]).rstrip() if cell.size else "")  # '' is empty
    return texts


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
                                        f"({variables.said(e)})") from None
