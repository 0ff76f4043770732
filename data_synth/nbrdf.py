"""Real materials offline: MERL tables rebuilt from the published neural BRDFs.

The 100 MERL materials ship as small MLPs (``data_synth/nbrdf/merl_nbrdf.zip``,
Sztrajman et al. 2021, MIT licence; see ``data_synth/nbrdf/README.md``). Each
network maps a direction pair in half/difference form to ``log(1 + f)`` per RGB
channel; evaluating it at every bin centre gives a table with a real material's
shape, which is what the real-material benchmark and tests fit.
"""

from __future__ import annotations

import functools
import io
import os
import zipfile

import numpy as np

from brdffit.io import merl
from brdffit.io.grid import bin_grid

WEIGHTS_ZIP = os.path.join(os.path.dirname(__file__), "nbrdf", "merl_nbrdf.zip")
_MEMBER = "merl_nbrdf/{name}.h5"
#: Rows per matrix product: bounds the (rows, 21) temporaries to a few MB.
_CHUNK = 1 << 18


@functools.cache
def material_names() -> tuple[str, ...]:
    """The shipped materials, sorted (``alum-bronze`` ... ``yellow-plastic``)."""
    with zipfile.ZipFile(WEIGHTS_ZIP) as z:
        return tuple(sorted(
            os.path.basename(n)[: -len(".h5")] for n in z.namelist() if n.endswith(".h5")
        ))


def load_weights(name: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """(kernel, bias) of the network's three dense layers, as float64 arrays."""
    import h5py  # a core dependency, but only this path needs it

    if name not in material_names():
        raise ValueError(
            f"unknown material {name!r}; `python -m data_synth nbrdf --list` names the "
            f"{len(material_names())} shipped ones"
        )
    with zipfile.ZipFile(WEIGHTS_ZIP) as z:
        blob = z.read(_MEMBER.format(name=name))
    with h5py.File(io.BytesIO(blob), "r") as f:
        return [
            (
                np.asarray(f[f"dense_{k}/dense_{k}/kernel:0"], np.float64),
                np.asarray(f[f"dense_{k}/dense_{k}/bias:0"], np.float64),
            )
            for k in (1, 2, 3)
        ]


def network_input(theta_h, theta_d, phi_d) -> np.ndarray:
    """(n, 6): the half vector (phi_h = 0) and the difference vector, the network's
    input layout."""
    sh, sd = np.sin(theta_h), np.sin(theta_d)
    return np.stack([sh, np.zeros_like(sh), np.cos(theta_h),
                     sd * np.cos(phi_d), sd * np.sin(phi_d), np.cos(theta_d)], axis=1)


def evaluate(layers, x: np.ndarray) -> np.ndarray:
    """The network at inputs ``x`` (n, 6) -> BRDF values (n, 3), 1/sr, >= 0."""
    out = np.empty((x.shape[0], 3))
    (k1, b1), (k2, b2), (k3, b3) = layers
    for s in range(0, x.shape[0], _CHUNK):
        h = np.maximum(x[s : s + _CHUNK] @ k1 + b1, 0.0)
        h = np.maximum(h @ k2 + b2, 0.0)
        out[s : s + _CHUNK] = np.expm1(h @ k3 + b3)
    return np.maximum(out, 0.0)  # the network's tiny negative outputs are noise


def make_table(name: str) -> merl.MerlTable:
    """The MERL-format table of material ``name``: the network at every bin centre
    above the horizon; bins below it unmeasured."""
    layers = load_weights(name)
    g = bin_grid()
    idx = np.flatnonzero(g.above_horizon)
    values = np.zeros((3, g.weight.size))
    values[:, idx] = evaluate(layers, network_input(g.theta_h[idx], g.theta_d[idx],
                                                    g.phi_d[idx])).T
    return merl.MerlTable.from_values(values, g.above_horizon, source=f"nbrdf:{name}")


def cached_table(name: str, directory: str) -> str:
    """Path of ``directory/NAME.binary``, written on first use (tables are 35 MB
    each and rebuilt in about a second: a cache, never committed)."""
    os.makedirs(directory, exist_ok=True)
    path = os.path.join(directory, f"{name}.binary")
    if not os.path.exists(path):
        merl.write(path, make_table(name))
    return path
