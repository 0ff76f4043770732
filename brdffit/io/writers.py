"""Writers of sample lists, in the layouts :mod:`brdffit.io.readers` reads back.

``write_samples(meas, path)`` chooses the layout by suffix: ``.astm`` (ASTM E1392 as
Cornell's files have it: radians, ``VARS theta_i,phi_i,theta_s,phi_s,R,G,B``), ``.csv``
or ``.tsv`` (a header naming each column with its unit, degrees), ``.h5``/``.hdf5``
(datasets in radians, their ``units`` attribute set). Values keep 9 significant
digits in text (a float's 17 would triple the file for nothing a measurement holds);
HDF5 keeps them exactly, and the list's provenance (read back, with ``stored_as``).
Sigma is written where the list has it (ASTM has no column
for it: refused rather than dropped).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from brdffit.errors import FitInputError
from brdffit.io.measurements import Measurements


def angles_of(meas: Measurements) -> tuple[np.ndarray, ...]:
    """(theta_i, phi_i, theta_o, phi_o) in radians, phi in [0, 2 pi)."""
    def polar(w):
        theta = np.arccos(np.clip(w[:, 2], -1.0, 1.0))
        phi = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * np.pi)
        return theta, phi

    return (*polar(meas.wi), *polar(meas.wo))


def _text_rows(columns: list[np.ndarray], delimiter: str) -> str:
    rows = np.column_stack(columns)
    return "\n".join(delimiter.join(f"{x:.9g}" for x in r) for r in rows) + "\n"


def write_astm(meas: Measurements, path: str | os.PathLike) -> Path:
    """ASTM E1392, as Cornell's gonioreflectometer files (radians, RGB)."""
    if meas.sigma is not None:
        raise FitInputError(f"{path}: ASTM E1392 has no column for sigma; write .csv or .h5")
    path = Path(path)
    head = (f"SOURCE {meas.source}\nNUM_POINTS {meas.n}\n"
            "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\n")
    path.write_text(head + _text_rows([*angles_of(meas), meas.rgb], ","))
    return path


def write_csv(meas: Measurements, path: str | os.PathLike) -> Path:
    """A CSV (``.csv``) or TSV (``.tsv``) with a header; angles in degrees."""
    path = Path(path)
    delimiter = "\t" if path.suffix.lower() == ".tsv" else ","
    names = ["theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b"]
    columns = [np.degrees(a) for a in angles_of(meas)] + [meas.rgb]
    if meas.sigma is not None:
        names += ["sigma_r", "sigma_g", "sigma_b"]
        columns.append(meas.sigma)
    path.write_text(f"# {meas.source}\n" + delimiter.join(names) + "\n"
                    + _text_rows(columns, delimiter))
    return path


def hdf5_bytes(n: int, sigma: bool) -> int:
    """The bytes of the datasets :func:`write_hdf5` writes for ``n`` samples (float64,
    uncompressed: four angles, rgb, and sigma where ``sigma``); HDF5's own headers and
    the attributes add a few KB. What a service that stores uploads so must budget for:
    a compressed upload of one value repeated is a few hundred times smaller."""
    return 8 * n * (4 + 3 + (3 if sigma else 0))


def write_hdf5(meas: Measurements, path: str | os.PathLike) -> Path:
    """HDF5 datasets (radians, ``units`` on each angle)."""
    import h5py

    path = Path(path)
    with h5py.File(path, "w") as f:
        for name, a in zip(("theta_i", "phi_i", "theta_o", "phi_o"), angles_of(meas),
                           strict=True):
            f.create_dataset(name, data=a).attrs["units"] = "radians"
        f.create_dataset("rgb", data=meas.rgb)
        if meas.sigma is not None:
            f.create_dataset("sigma", data=meas.sigma)
        f.attrs["source"] = str(meas.source)
        # what the list was before it was stored here (its format, columns, spectral
        # projection): read back by brdffit.io.named_arrays.read_hdf5
        f.attrs["provenance"] = json.dumps(meas.provenance)
    return path


#: suffix -> writer
WRITERS = {".astm": write_astm, ".csv": write_csv, ".tsv": write_csv, ".h5": write_hdf5,
           ".hdf5": write_hdf5}


def write_samples(meas: Measurements, path: str | os.PathLike) -> Path:
    """``meas`` written in the layout ``path``'s suffix names (module docstring)."""
    writer = WRITERS.get(Path(path).suffix.lower())
    if writer is None:
        raise FitInputError(f"{path}: no sample layout has this suffix; choose one of "
                            f"{', '.join(WRITERS)}")
    return writer(meas, path)
