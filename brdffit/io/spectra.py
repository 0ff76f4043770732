"""Spectral samples projected to linear sRGB, with the illuminant stated.

A spectral gonioreflectometer measures f_r(lambda) at a set of wavelengths. Every model
here is RGB, so each sample's spectrum becomes the linear sRGB (Rec. 709 primaries)
reflectance a renderer would make of it under white light:

    R_c = int w_c(lambda) f(lambda) d lambda,   w_c = [M xyz(lambda)]_c D65(lambda),

the CIE 1931 2-degree observer under D65, each w_c normalised so that a flat spectrum
of 1 is (1, 1, 1) (:mod:`brdffit.io.srgb_response`, Mitsuba's own tables: an export to
Mitsuba's spectral variants turns the RGB back into the same light). The measured
spectrum is linear between its wavelengths and held at its end values beyond them;
the wavelengths must span at least :data:`MIN_SPAN` (where the responses hold ~99% of
their weight), else the projection would be mostly the hold, and it is refused, as are
wavelengths more than :data:`MAX_GAP` apart there. A
spectrum outside sRGB's gamut (a channel below 0: the responses have negative lobes)
is clipped to 0 there, and ``outside_srgb`` counts them.
"""

from __future__ import annotations

import numpy as np

from brdffit.io import srgb_response
from brdffit.io.measurements import MeasurementsError

#: The range (nm) a spectrum's wavelengths must cover to be projected.
MIN_SPAN = (420.0, 680.0)
#: The widest gap (nm) between two wavelengths within :data:`MIN_SPAN` that a spectrum
#: may have: across a wider one its colour is the straight line drawn between them, not
#: a measurement (three lasers, 405, 532 and 690 nm, were projected to a colour 15% off
#: in red without a word). A multispectral camera's 50 nm steps pass.
MAX_GAP = 100.0
#: The integration grid (nm): Mitsuba's range, every nm.
GRID = np.arange(360.0, 831.0, 1.0)
#: What every projected sample list's provenance says of it.
PROJECTION = {"illuminant": "D65", "observer": "CIE 1931 2 deg",
              "rgb": "linear sRGB (Rec. 709 primaries)",
              "beyond_range": "held at the end values"}


def to_rgb(values: np.ndarray, wavelengths, source: str) -> tuple[np.ndarray, dict]:
    """``values`` (n, k) at ``wavelengths`` (k,) in nm as linear sRGB (n, 3), and the
    provenance entry that says how. Wavelengths in another order (longest first) are
    sorted, each with its values, and the entry says so. Raises
    :class:`MeasurementsError` for wavelengths that are not finite and distinct, or
    not spanning :data:`MIN_SPAN`."""
    lam = np.asarray(wavelengths, float).ravel()
    values = np.asarray(values, float)
    if values.ndim != 2 or values.shape[1] != lam.size:
        raise MeasurementsError(source, f"{lam.size} wavelengths but spectra of shape "
                                        f"{values.shape}")
    resorted = False
    if lam.size >= 2 and np.all(np.isfinite(lam)) and np.any(np.diff(lam) < 0):
        # columns written longest wavelength first (some spectrometers' order): each
        # value keeps its own wavelength, so sorting them changes no measurement (a
        # wavelength given twice is refused below, sorted or not)
        order = np.argsort(lam, kind="stable")
        lam, values, resorted = lam[order], values[:, order], True
    if lam.size < 2 or not np.all(np.isfinite(lam)) or np.any(np.diff(lam) <= 0):
        raise MeasurementsError(source, "the wavelengths must be finite and distinct, at "
                                        f"least two (got {lam.tolist()[:8]})")
    if lam[0] > MIN_SPAN[0] or lam[-1] < MIN_SPAN[1]:
        unit = (" (micrometres? wavelengths are read in nm: multiply them by 1000)"
                if 0.3 <= lam[0] and lam[-1] <= 3.0 else
                " (metres? wavelengths are read in nm)" if lam[-1] < 1e-5 else "")
        raise MeasurementsError(
            source, f"the spectra span {lam[0]:g}-{lam[-1]:g} nm{unit}; projecting to RGB "
                    f"needs at least {MIN_SPAN[0]:g}-{MIN_SPAN[1]:g} nm (where the eye's "
                    "response is), else the colour would be mostly a guess")
    # the gaps that cross the visible span (a gap wholly outside it weighs ~nothing)
    gaps = np.diff(lam)
    crossing = (lam[1:] > MIN_SPAN[0]) & (lam[:-1] < MIN_SPAN[1])
    widest = int(np.argmax(np.where(crossing, gaps, -1.0)))
    if crossing.any() and gaps[widest] > MAX_GAP:
        raise MeasurementsError(
            source, f"the spectra have {lam.size} wavelengths, {gaps[widest]:g} nm apart "
                    f"between {lam[widest]:g} and {lam[widest + 1]:g} nm: the colour there "
                    "would be the straight line drawn across the gap, not a measurement; "
                    f"projecting to RGB needs wavelengths at most {MAX_GAP:g} nm apart over "
                    f"{MIN_SPAN[0]:g}-{MIN_SPAN[1]:g} nm (three bands that are the colour's "
                    "own: name their columns r, g, b)")
    weights = srgb_response.responses(GRID)  # (grid, 3), each column integrates to 1
    dl = np.gradient(GRID)
    dl[0] *= 0.5
    dl[-1] *= 0.5
    matrix = interpolation_matrix(lam, GRID) @ (weights * dl[:, None])  # (k, 3)
    rgb = values @ matrix
    # a saturated spectrum (a narrow band near 500 nm) lies outside sRGB's gamut: a
    # channel below 0, which no reflectance is; clipped there, and counted
    outside = np.any(rgb < 0, axis=1)
    info = {"wavelengths_nm": [float(lam[0]), float(lam[-1]), int(lam.size)], **PROJECTION,
            "outside_srgb": int(outside.sum())}
    if resorted:
        info["wavelength_order"] = "not increasing in the file: read sorted"
    return np.maximum(rgb, 0.0), info


def interpolation_matrix(lam: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """(k, g): row ``j`` is ``np.interp(grid, lam, e_j)``, each wavelength's share of
    each grid point under linear interpolation, held at the end values beyond ``lam``.
    Interpolation is linear in the values, so a projection of spectra is one matrix.
    Built from each grid point's two neighbours: interpolating the k unit vectors one by
    one cost O(k^2 g) (6,000 wavelengths: minutes)."""
    at = np.clip(grid, lam[0], lam[-1])
    hi = np.clip(np.searchsorted(lam, at, side="right"), 1, lam.size - 1)
    lo = hi - 1
    t = (at - lam[lo]) / (lam[hi] - lam[lo])
    out = np.zeros((lam.size, grid.size))
    columns = np.arange(grid.size)
    out[lo, columns] = 1.0 - t  # lo and hi are two rows of each column: no sum needed
    out[hi, columns] = t
    return out


def wavelength_of(name: str) -> float | None:
    """The wavelength (nm) a CSV column names (``450nm``, ``f_450nm``, ``nm450``, and a
    wavelength's word with its number, ``lambda_450``, ``wl450``, ``λ450``, in nm: a
    spectrum in other units is refused by its span, :func:`to_rgb`; a bare ``450`` is not
    spectral), or None. (``lambda_400``, ``lambda_410``, ... were read as two columns
    that each say which wavelength a row holds, and the message said to keep one.)"""
    import re

    m = re.fullmatch(r"(?:f_?|r_?|brdf_?)?(\d+(?:\.\d+)?)\s*nm|nm_?(\d+(?:\.\d+)?)|"
                     r"(?:lambda|λ|wl|wavelength)_?(\d+(?:\.\d+)?)(?:\s*_?nm)?",
                     name.strip().lower())
    if m is None:
        return None
    return float(m[1] or m[2] or m[3])


def projected(values: np.ndarray, wavelengths, source: str, row_numbers=None):
    """Spectra (n, k) of a sample list, checked as any value is (finite, >= 0; the first
    bad one named by its row, ``row_numbers`` where the file's rows are not the
    samples'), then :func:`to_rgb`."""
    bad = ~np.all(np.isfinite(values), axis=1) | np.any(values < 0, axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        row = first if row_numbers is None else int(row_numbers[first])
        raise MeasurementsError(source, f"a spectral value is negative or not finite in "
                                        f"{int(bad.sum())} rows (first: row {row + 1})")
    return to_rgb(values, wavelengths, source)
