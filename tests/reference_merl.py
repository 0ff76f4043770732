"""An independent MERL writer, in plain numpy, written from docs/models.md alone.

It shares no code with brdffit or data_synth: its own bin-centre geometry (explicit
rotation matrices), its own model formulas (as docs/models.md writes them: tan, acos,
atan2, no rewrites), its own file writing (struct). A table it writes and brdffit
fits is a check that a bug shared by brdffit's models and data_synth cannot hide.
"""

from __future__ import annotations

import math
import struct

import numpy as np
from scipy.special import erf

SCALE = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)


def _rot_y(t):
    c, s = np.cos(t), np.sin(t)
    z, o = np.zeros_like(t), np.ones_like(t)
    return np.stack(
        [np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2
    )


def bin_centre_directions():
    """wi, wo (N, 3) at every bin centre, flat MERL order (phi_d fastest)."""
    i = np.arange(90)
    th = ((i + 0.5) / 90) ** 2 * (math.pi / 2)
    td = (i + 0.5) / 90 * (math.pi / 2)
    pd = (np.arange(180) + 0.5) / 180 * math.pi
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    TH, TD, PD = TH.ravel(), TD.ravel(), PD.ravel()
    d = np.stack([np.sin(TD) * np.cos(PD), np.sin(TD) * np.sin(PD), np.cos(TD)], -1)
    # d is wi rotated by -theta_h about y (phi_h = 0), so wi = R_y(theta_h) d
    R = _rot_y(TH)
    wi = np.einsum("nij,nj->ni", R, d)
    h = np.einsum("nij,j->ni", R, np.array([0.0, 0.0, 1.0]))
    wo = 2 * np.sum(wi * h, -1, keepdims=True) * h - wi
    return wi, wo


def _angles(wi, wo):
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    return h


def evaluate(model: str, p: dict, wi, wo) -> np.ndarray:
    """f_r (N, 3) straight from docs/models.md's table."""
    kd = np.asarray(p["kd"], float) * np.ones(3)
    ci, co = wi[:, 2], wo[:, 2]
    h = _angles(wi, wo)
    ch = h[:, 2]
    cd = np.sum(wi * h, -1)
    if model == "lambert":
        return np.tile(kd / math.pi, (len(ci), 1))
    if model == "oren_nayar":
        s2 = p["sigma"] ** 2
        A = 1 - s2 / (2 * (s2 + 0.33))
        B = 0.45 * s2 / (s2 + 0.09)
        ti, to = np.arccos(ci), np.arccos(co)
        phi_i, phi_o = np.arctan2(wi[:, 1], wi[:, 0]), np.arctan2(wo[:, 1], wo[:, 0])
        a, b = np.maximum(ti, to), np.minimum(ti, to)
        g = A + B * np.maximum(0, np.cos(phi_i - phi_o)) * np.sin(a) * np.tan(b)
        return kd / math.pi * g[:, None]
    ks = np.asarray(p["ks"], float) * np.ones(3)
    if model == "phong":
        n = p["n"]
        r = np.stack([-wi[:, 0], -wi[:, 1], wi[:, 2]], -1)
        lobe = (n + 2) / (2 * math.pi) * np.maximum(0, np.sum(r * wo, -1)) ** n
    elif model == "blinn_phong":
        n = p["n"]
        lobe = (n + 2) / (2 * math.pi) * ch**n
    else:
        a = p["alpha"]
        tan2 = lambda c: (1 - c * c) / (c * c)  # noqa: E731
        if model == "ggx":
            D = a**2 / (math.pi * (ch**2 * (a**2 - 1) + 1) ** 2)
            lam = lambda c: (-1 + np.sqrt(1 + a**2 * tan2(c))) / 2  # noqa: E731
        elif model == "beckmann":
            D = np.exp(-tan2(ch) / a**2) / (math.pi * a**2 * ch**4)

            def lam(c):
                with np.errstate(divide="ignore", invalid="ignore"):
                    m = 1 / (a * np.sqrt(tan2(c)))
                    out = (erf(m) - 1) / 2 + np.exp(-m * m) / (2 * m * math.sqrt(math.pi))
                return np.where(np.isfinite(m), out, 0.0)
        else:
            raise ValueError(model)
        G = 1 / (1 + lam(ci) + lam(co))
        F = p["f0"] + (1 - p["f0"]) * (1 - cd) ** 5
        lobe = F * D * G / (4 * ci * co)
    return kd / math.pi + ks * lobe[:, None]


def write(path, model: str, params: dict) -> np.ndarray:
    """Write a MERL file; returns the physical values (3, N) that it encodes."""
    wi, wo = bin_centre_directions()
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    vals = np.zeros((len(wi), 3))
    with np.errstate(all="ignore"):
        vals[above] = evaluate(model, params, wi[above], wo[above])
    raw = np.where(above[None], vals.T / np.array(SCALE)[:, None], -1.0)
    with open(path, "wb") as f:
        f.write(struct.pack("<3i", 90, 90, 180))
        f.write(raw.astype("<f8").tobytes())
    return np.where(above[None], vals.T, np.nan)
