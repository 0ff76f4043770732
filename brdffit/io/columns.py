"""What a sample list's columns and datasets are called, and what they say of their
units: one vocabulary for every layout, a CSV's or ASTM file's columns
(:mod:`brdffit.io.text_samples`) and an HDF5, MATLAB or .npz file's datasets
(:mod:`brdffit.io.named_arrays`).

The names brdffit reads (``theta_i``, ``phi_o``, ``r``, ``value``, ``sigma_g``), their
aliases (``theta_s``, ``Red [1/sr]``, ``theta_i (deg)``), the names it refuses with a
reason (CIE XYZ, one row per channel, an uncertainty by another name than sigma), and
the judgements of units made on the numbers themselves (radians said to be degrees).
"""

from __future__ import annotations

import re

import numpy as np

from brdffit.io.measurements import HORIZON_SLACK, MeasurementsError, angles_checked

#: Column name -> the canonical name (light ``_i``, view ``_o``).
ANGLE_ALIASES = {
    "theta_i": "theta_i", "phi_i": "phi_i", "theta_in": "theta_i", "phi_in": "phi_i",
    "theta_l": "theta_i", "phi_l": "phi_i",
    "theta_o": "theta_o", "phi_o": "phi_o", "theta_out": "theta_o", "phi_out": "phi_o",
    "theta_r": "theta_o", "phi_r": "phi_o", "theta_s": "theta_o", "phi_s": "phi_o",
    "theta_v": "theta_o", "phi_v": "phi_o",
}
#: The value columns of RGB samples, and the names one grey channel may have.
CHANNELS = ("r", "g", "b")
ONE_CHANNEL = ("value", "brdf", "y")
#: Columns that say which channel, wavelength or polarisation a row holds: a file of
#: one row per (direction, channel), a "long" layout (:mod:`brdffit.io.long_layout`).
#: They are known by a word of their name (``rgb_channel``, ``Channel_ID``, ``WL_nm``,
#: ``wave_length``: a channel column under a name outside a short list was not seen,
#: and its rows were read as grey samples of the same directions). A channel column's
#: cells name R, G, B (``r``, ``Red``) or a wavelength (``450nm``);
CHANNEL_WORDS_IN_NAMES = frozenset({"channel", "channels", "chan", "ch", "band", "bands",
                                    "color", "colors", "colour", "colours", "filter",
                                    "filters"})
#: a wavelength column's are nanometres;
WAVELENGTH_WORDS = frozenset({"wavelength", "wavelengths", "lambda", "λ", "wl", "lam"})
#: a polarisation state is not read (which average of two states the measurement stands
#: for depends on the instrument).
POLARISATION_WORDS = frozenset({"polarization", "polarisation", "polarizer", "polariser",
                                "pol"})
ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")


def long_column_kind(name: str) -> str | None:
    """``"channel"``, ``"wavelength"`` or ``"polarisation"`` where a lower-case column
    or dataset name, less a unit (``wavelength [nm]``), holds one of their words
    (:data:`CHANNEL_WORDS_IN_NAMES`, :data:`WAVELENGTH_WORDS`, :data:`POLARISATION_WORDS`;
    ``wave_length``; ``nm`` alone); else None. A spectral value column named by its
    wavelength (``450nm``) is none of them."""
    from brdffit.io.spectra import wavelength_of

    if wavelength_of(name) is not None or angle_name(name) is not None:
        return None
    words = set(re.findall(r"[a-zλ]+", re.split(r"[\[(/]", name, maxsplit=1)[0]))
    if words & POLARISATION_WORDS:
        return "polarisation"
    if words & WAVELENGTH_WORDS or {"wave", "length"} <= words or words == {"nm"}:
        return "wavelength"
    return "channel" if words & CHANNEL_WORDS_IN_NAMES else None


def stated_unit(name: str) -> str | None:
    """The unit a column's name states after it (``wavelength [um]``, ``lambda (µm)``,
    ``wl/nm``) or as its last word (``wavelength_um``, ``WL_nm``), lower-case; None."""
    m = re.search(r"[\[(/]\s*([^\])]*?)\s*[\])]?\s*$", name)
    if m:
        return m[1].strip().lower() or None
    last = re.findall(r"[a-zµμ]+", name.lower())
    return last[-1] if len(last) > 1 and last[-1] in ("nm", "um", "µm", "μm", "micron",
                                                      "microns", "m", "mm", "a") else None


def unit_scale(unit: str, source: str) -> float:
    """Radians per ``unit``: degrees or radians, in any of their spellings (``deg``,
    ``radian``); any other unit is refused."""
    unit = unit.strip().lower()
    if unit in ("deg", "degree", "degrees", "°", "º", "deg.", "degs"):
        return np.pi / 180.0
    if unit in ("rad", "radian", "radians"):
        return 1.0
    raise MeasurementsError(source, f"unknown angle unit {unit!r}: degrees or radians")


#: A value column's unit written after its name, which is the BRDF's own (1/sr): read
#: as the name alone (``r [1/sr]``, ``brdf (sr^-1)``). Any other unit is not stripped,
#: so that such a column is not read as a BRDF.
PER_STERADIAN = re.compile(r"[\[(]\s*(?:1\s*/\s*sr|sr\s*\^?\s*-\s*1|sr⁻¹)\s*[\])]")
#: Spelled-out channel names, as some instruments' exports write them.
CHANNEL_WORDS = {"red": "r", "green": "g", "blue": "b"}


def value_name(name: str) -> str:
    """A lower-case column name without a per-steradian unit, its channel spelled
    as brdffit's (``Red [1/sr]`` is ``r``)."""
    # from the last bracket on: a pattern searched from the start would try each
    # space of a long run before it (quadratic in the name)
    last = max(name.rfind("["), name.rfind("("))
    if last >= 0 and PER_STERADIAN.fullmatch(name, last):
        name = name[:last].rstrip()
    name = CHANNEL_WORDS.get(name, name)
    return _brdf_channel(name) or name


def _brdf_channel(name: str) -> str | None:
    """``r`` of ``BRDF R``, ``brdf_red``, ``Red BRDF`` or ``BRDF (1/sr) R`` (a merged
    group's name before its column's): the word brdf, one channel's, and at most the
    per-steradian unit; None for any other name."""
    if len(name) > 80 or "brdf" not in name:  # a column's name is short; most are not this
        return None
    rest = PER_STERADIAN.sub(" ", name)
    if not re.fullmatch(r"[a-z_\s.-]+", rest):  # another unit ([%], (a.u.)) is not 1/sr
        return None
    words = re.findall(r"[a-z]+", rest)
    if len(words) != 2 or "brdf" not in words:
        return None
    channel = words[1] if words[0] == "brdf" else words[0]
    channel = CHANNEL_WORDS.get(channel, channel)
    return channel if channel in CHANNELS else None


def unit_suffixed(name: str) -> str:
    """An angle column's name with its unit written as a suffix: ``theta_i [deg]``,
    ``theta_i (deg)``, ``theta_i (°)``, ``theta_i deg`` and ``theta_i/rad`` are read as
    ``theta_i_deg`` and ``theta_i_rad``, as lab software and spreadsheets write them.

    Read from the end with string methods, in time linear in the name: one regular
    expression for all four forms could split a run of spaces between its parts in
    cubic many ways (a 16 KB header with a long run of spaces in one name took 110 s
    to read)."""
    name = name.replace("°", "deg").replace("º", "deg")
    for opening, closing in ("[]", "()"):
        if name.endswith(closing):
            head, found, unit = name[:-1].rpartition(opening)
            unit = unit.strip()
            if found and _WORD.fullmatch(unit):
                return f"{head.rstrip()}_{unit}"
            return name
    start = len(name)
    while start > 0 and _WORD.fullmatch(name[start - 1]):
        start -= 1
    unit, before = name[start:], name[:start].rstrip()
    if unit and before.endswith("/"):
        return f"{before[:-1].rstrip()}_{unit}"
    if unit and 0 < start and name[start - 1].isspace():
        return f"{before}_{unit}"
    return name


_WORD = re.compile(r"\w+")


#: A column of CIE XYZ by its name: ``CIE_X``, ``X (CIE)``, ``xyz_z``.
_CIE_NAME = re.compile(r"(?:cie|xyz)[\s_.-]*[xyz]|[xyz][\s_.-]*[\[(]?cie[\])]?")


def cie_xyz(names) -> list[str]:
    """Those of the lower-case column or dataset ``names`` that hold CIE XYZ, where
    they do: ``x``, ``y`` and ``z``, or any named as CIE's (``CIE_X`` beside a ``Y``
    read ``Y`` alone as grey); else none."""
    bare = {"x", "y", "z"} & set(names)
    xyz = [n for n in names if n in bare or _CIE_NAME.fullmatch(n)]
    return xyz if len(bare) == 3 or len(xyz) > len(bare) else []


#: Why CIE XYZ values are refused (a CSV's x, y, z columns; HDF5's X, Y, Z datasets).
XYZ_WHY = ("CIE XYZ? A fit reads linear RGB (r, g, b: Rec. 709 primaries) or one grey "
           "channel: convert XYZ to linear sRGB, or keep y alone (named value) to fit the "
           "luminance")


#: Why a polarisation column or dataset is refused (a CSV's, an HDF5 file's).
POLARISED_WHY = ("a polarisation-resolved list is not read (which average of its states "
                 "the reflectance is depends on the instrument); write the unpolarised "
                 "values, one row per direction pair")
#: What two columns (or datasets) that each name a row's channel or wavelength are told.
TWO_LONG = "both say which channel or wavelength a row holds: keep one"


#: A column of each value's uncertainty by another name than brdffit's ``sigma_r``:
#: ``r_std``, ``std_r``, ``R_err``, ``uncertainty``. It was dropped unsaid, and the fit
#: weighted every sample alike.
_VALUE_WORDS = "|".join((*CHANNELS, *CHANNEL_WORDS, *ONE_CHANNEL, "rgb"))
UNCERTAINTY = re.compile(
    rf"(?:(?:{_VALUE_WORDS})[\s_.-]*)?"
    r"(?:std|stdev|stddev|std_dev|sd|se|sem|stderr|std_err|sigma|err|error|unc|uncertainty"
    r"|var|variance|ci|ci95|ci_95|conf)"
    rf"(?:[\s_.-]*(?:{_VALUE_WORDS}))?")


#: A column or dataset of the light falling on the sample (an irradiance, a lamp's
#: power): beside it the values are most likely radiances, not a BRDF. A review's
#: ``value,irradiance`` file was fitted as a BRDF (kd 3.5), the irradiance unsaid.
IRRADIANCE = re.compile(
    r"(?:irradiance|illuminance|e_?i|e_?in"
    r"|(?:incident|incoming|source|lamp)[\s_.-]*(?:power|flux|intensity|irradiance))"
    r"(?:[\s_.-]*(?:incident|in|i|w/m2|w/m\^?2|w m-2|lx|lux|\[.*\]|\(.*\)))*")
#: A value column named as a radiance (no BRDF column beside it).
RADIANCE = re.compile(r"(?:reflected[\s_.-]*|outgoing[\s_.-]*)?(?:radiance|luminance|l_?o)"
                      r"(?:[\s_.-]*(?:\[.*\]|\(.*\)|[rgb]|red|green|blue))*")
#: What a file with a radiance or an irradiance is told.
RADIANCE_IS = ("brdffit reads a BRDF, in 1/sr: the reflected radiance over the irradiance "
               "that made it (L_o / E_i, E_i on the sample's surface). Divide them, write "
               "the result as r, g, b (or value), and leave the irradiance out")

#: What a refused uncertainty column or dataset is told: what sigma is, what to do.
SIGMA_IS = ("their standard deviation, in 1/sr. Rename it so to weigh the fit by it, or "
             "drop it")


#: Fewer samples than this are not judged by :func:`polar_unit_checked`.
_JUDGED_FROM = 3


def _radians_said_to_be_degrees(raw: list[np.ndarray], scales: list[float],
                                source: str) -> None:
    """Refuses polar angles in degrees (``scales``) whose numbers all fit radians' range,
    pi/2: read as degrees, the whole list sits within 1.6 degrees of the normal, where
    no lobe can be fitted. The azimuths are not asked: a lab that writes its polar angles
    in radians and its azimuths in degrees had its fit called good, ks 0.0004 for 0.8.
    The other mistake (degrees said to be radians) is refused by the angles' bounds."""
    n = raw[0].size
    if n < _JUDGED_FROM or any(scale == 1.0 for scale in scales[0::2]):
        return
    polar, azimuth = np.abs(np.concatenate(raw[0::2])), np.abs(np.concatenate(raw[1::2]))
    if np.all(polar <= np.pi / 2 + HORIZON_SLACK) and np.max(polar) > 0.2:
        mixed = ("" if np.all(azimuth <= 2 * np.pi + 1e-6) else
                 "; the azimuths reach beyond 2 pi, as degrees do: polar angles in radians "
                 "beside azimuths in degrees?")
        raise MeasurementsError(
            source, f"the angles are said to be in degrees, but all {n} samples' polar "
                    f"angles are within {np.pi / 2:.4f}, radians' range (as degrees, every "
                    f"direction would be within 1.6 degrees of the normal){mixed}. If the "
                    "polar angles are radians, name their columns _rad (theta_i_rad beside "
                    "phi_i_deg is read), or put '# angles: radians' before the header (HDF5: "
                    "a units attribute 'radians')")


def _degrees_said_to_be_radians(raw: list[np.ndarray], scales: list[float],
                               source: str) -> None:
    """Refuses polar angles in radians (``scales``) of which a quarter or more lie past
    the horizon, pi/2, and all within 90: degrees under a radians name, most likely.
    They read as "below the horizon in 67 rows", with neither the value nor the unit
    said. A list with a few bad rows is left to that refusal, row by row."""
    n = raw[0].size
    if n < _JUDGED_FROM or any(scale != 1.0 for scale in scales[0::2]):
        return
    polar = np.abs(np.concatenate(raw[0::2]))
    if not np.all(np.isfinite(polar)):
        return
    past = polar > np.pi / 2 + HORIZON_SLACK
    if np.mean(past) >= 0.25 and np.all(polar <= 90.0 + HORIZON_SLACK):
        raise MeasurementsError(
            source, f"the angles are said to be in radians, but {np.count_nonzero(past):,} of "
                    f"the {polar.size:,} polar angles are past pi/2 (up to {polar.max():.4g}), "
                    "and all are within 90: degrees? Name their columns _deg (theta_i_deg), "
                    "or put '# angles: degrees' before the header (HDF5: a units attribute "
                    "'degrees')")


def polar_unit_checked(raw: list[np.ndarray], scales: list[float], source: str) -> None:
    """Refuses polar angles whose numbers contradict the unit they are said to be in,
    either way (:func:`_radians_said_to_be_degrees`, :func:`_degrees_said_to_be_radians`),
    ``raw`` as written and ``scales`` their radians per unit."""
    _radians_said_to_be_degrees(raw, scales, source)
    _degrees_said_to_be_radians(raw, scales, source)


#: From this many samples, azimuths are judged by :func:`azimuths_within`.
_AZIMUTHS_JUDGED_FROM = 20
#: pi as a file writes it (3.14, 3.1416, 3.14159265): an in-plane list's other azimuth
_PI_AS_WRITTEN = 2e-3


def azimuths_within(raw: list[np.ndarray], scales: list[float]) -> dict:
    """``{"azimuths_within_deg": x}`` where the azimuths are said to be in degrees yet
    all lie within 2 pi, reach beyond pi (or, an in-plane list's, are each 0 or pi), and
    are mostly not whole degrees: radians under a degrees header, most likely (every
    direction then sits within 6.3 degrees of one azimuth, and the fit was made without
    a word; an in-plane list of phi_o 0 or 3.14159 read as degrees was fitted kd 1.1,
    poor, with next steps none of which could help). Only noted (the fit's notes and
    its first next step), not refused: a list measured close to its plane of incidence
    reads so too."""
    if raw[0].size < _AZIMUTHS_JUDGED_FROM or any(scale == 1.0 for scale in scales[1::2]):
        return {}
    azimuth = np.abs(np.concatenate(raw[1::2]))
    azimuth = azimuth[azimuth != 0]  # phi_i 0, by a common convention, says nothing
    if azimuth.size < _AZIMUTHS_JUDGED_FROM or not np.all(np.isfinite(azimuth)):
        return {}
    largest = float(azimuth.max())
    whole = np.mean(azimuth == np.round(azimuth))
    in_plane = bool(np.all(np.abs(azimuth - np.pi) < _PI_AS_WRITTEN))
    if largest <= 2 * np.pi + 1e-6 and (largest > np.pi or in_plane) and whole < 0.5:
        return {"azimuths_within_deg": largest}
    return {}


def angle_name(name: str) -> re.Match | None:
    """An angle column's name read (``theta_i_deg``, ``Theta_S [rad]``, ``phi_o``, or in
    words, :func:`_angle_in_words`: ``Incident theta (deg)``, ``view azimuth``,
    ``θi (°)``): groups the angle's name and its unit, if any; None for any other
    column."""
    suffixed = unit_suffixed(value_name(name.strip().lower()))
    m = _ANGLE.fullmatch(suffixed)
    if m is not None and f"{m[1]}_{m[2]}" in ANGLE_ALIASES:
        return m
    spelled = _angle_in_words(suffixed)
    return None if spelled is None else _ANGLE.fullmatch(spelled)


# every spelling unit_scale reads: a units row of "degree" was accepted, then its
# columns (theta_i [degree]) found no angle
_ANGLE = re.compile(r"(theta|phi)_([a-z]+?)(?:_(deg|rad|degrees?|radians?))?")
_ANGLE_UNITS = frozenset({"deg", "rad", "degree", "degrees", "radian", "radians"})
#: Words that name which angle of a direction (``elevation`` is not one: it is 90
#: degrees less the zenith angle, and is left unread rather than read as theta).
_ANGLE_KIND_WORDS = {"theta": "theta", "θ": "theta", "zenith": "theta", "polar": "theta",
                     "phi": "phi", "φ": "phi", "ϕ": "phi", "azimuth": "phi",
                     "azimuthal": "phi", "azi": "phi"}
#: Words that name whose direction: the light's or the view's. Not ``d`` or ``h``:
#: theta_d and theta_h are Rusinkiewicz's difference and half angles, not directions.
_ANGLE_SIDE_WORDS = {
    # not "in" (theta_in is read above, by name): "theta (in degrees)" is no light's
    **dict.fromkeys(("i", "inc", "incident", "incidence", "incoming", "illumination",
                     "illum", "light", "lighting", "source", "src", "l"), "i"),
    **dict.fromkeys(("o", "out", "outgoing", "r", "refl", "reflected", "reflection", "v",
                     "view", "viewing", "viewer", "s", "scatter", "scattered", "scattering",
                     "detector", "det", "camera", "cam", "sensor", "observer",
                     "observation", "obs", "exit", "emergent", "emergence", "e"), "o"),
}
_ANGLE_FILLER = frozenset({"angle", "angles", "of", "the", "direction", "dir"})


def _angle_in_words(name: str) -> str | None:
    """``theta_i`` (with ``_deg`` or ``_rad`` where it ends with a unit) for a name that
    says an angle in words, in any order and with any separators: one word of which
    angle (theta, zenith, phi, azimuth, θ, φ), one of whose (incident, light, source;
    view, outgoing, reflected, scattered, detector, camera), and nothing else but
    ``angle`` or ``of``, and at most one unit (``Incidence zenith angle``,
    ``theta_view``, ``θo``, ``incident (deg) theta``: a merged group's name before its
    column's). None for any other name: a word unknown, or two of one kind, reads as no
    angle."""
    words = re.findall(r"[a-z0-9]+|[θφϕ][a-z]*", name)
    # θi, φ_o: the Greek letter and its side as one word
    words = [part for w in words for part in ((w[0], w[1:]) if w[0] in "θφϕ" and w[1:]
                                              else (w,))]
    units = [w for w in words if w in _ANGLE_UNITS]  # at the end, or of a group's name
    if len(units) > 1:
        return None
    unit = units[0] if units else None
    words = [w for w in words if w not in _ANGLE_UNITS]
    kinds = [_ANGLE_KIND_WORDS[w] for w in words if w in _ANGLE_KIND_WORDS]
    sides = [_ANGLE_SIDE_WORDS[w] for w in words if w in _ANGLE_SIDE_WORDS]
    rest = [w for w in words if w not in _ANGLE_KIND_WORDS and w not in _ANGLE_SIDE_WORDS
            and w not in _ANGLE_FILLER]
    if len(set(kinds)) != 1 or len(set(sides)) != 1 or rest:  # "incident light theta": one
        return None
    return f"{kinds[0]}_{sides[0]}" + (f"_{unit}" if unit else "")


#: Rusinkiewicz's half and difference angles: a sample list may give its directions by
#: them, as the MERL table is indexed (phi_h 0 where it is absent: the material is
#: isotropic, and every model here is).
HALF_DIFF = ("theta_h", "theta_d", "phi_d", "phi_h")


def half_diff_name(name: str) -> re.Match | None:
    """A half or difference angle's column name read (``theta_h_deg``, ``Phi_d [rad]``,
    ``theta_d (°)``): groups the angle and its unit, if any; None for any other."""
    return re.fullmatch(r"(theta_h|theta_d|phi_d|phi_h)(?:_(deg|rad|degrees?|radians?))?",
                        unit_suffixed(value_name(name.strip().lower())))


def half_diff_as_directions(raw: list[np.ndarray], scales: list[float], source: str,
                            rows: np.ndarray | None = None,
                            names: list[str] | None = None) -> tuple[list[np.ndarray],
                                                                      list[float]]:
    """``[theta_i, phi_i, theta_o, phi_o]`` (radians; their scales 1) of half and
    difference angles as written (``raw``: theta_h, theta_d, phi_d and optional phi_h,
    :data:`HALF_DIFF`'s order; ``scales`` their radians per unit), by the table's own
    mapping (``brdffit.io.angles.half_diff_to_dirs``). Their units are judged first as a
    direction's are (:func:`polar_unit_checked`: theta_h and theta_d polar angles, the
    others azimuths): radians under a degrees header put every direction within 1.5
    degrees of the normal, unsaid. Then their range, as a direction's angles' is
    (:func:`brdffit.io.measurements.angles_checked`, naming ``rows``, each sample's row
    in its file, and each angle by ``names``, as the file has them): the mapping
    makes a pair of a negative theta_h or theta_d, or of a phi_d of 1e6 degrees, and
    such a list was fitted without a word."""
    from brdffit.io.angles import half_diff_to_dirs

    phi_h = (raw[3], scales[3]) if len(raw) > 3 else (np.zeros_like(raw[0]), scales[2])
    polar_unit_checked([raw[0], raw[2], raw[1], phi_h[0]],
                       [scales[0], scales[2], scales[1], phi_h[1]], source)
    half = [a * scale for a, scale in zip(raw, scales, strict=True)]
    said = dict(zip(HALF_DIFF, names or HALF_DIFF, strict=False))
    angles_checked(dict(zip(HALF_DIFF, half, strict=False)), source, rows,
                   lambda angle: said[angle])
    wi, wo = half_diff_to_dirs(*half[:3], half[3] if len(half) > 3 else 0.0)
    angles = []
    for w in (wi, wo):
        angles += [np.arccos(np.clip(w[..., 2], -1.0, 1.0)), np.arctan2(w[..., 1], w[..., 0])]
    return angles, [1.0] * len(ANGLES)


def an_angle_unit(unit: str | None) -> bool:
    """Whether ``unit`` is an angle's (:func:`unit_scale` reads it)."""
    try:
        return unit is not None and unit_scale(unit, "") > 0
    except MeasurementsError:
        return False
