"""MERL ``.binary`` BRDF tables (Matusik et al. 2003): read, write, look up.

File layout (docs/models.md): three little-endian int32 dims (90, 90, 180), then
3 * 90*90*180 little-endian float64, all R then all G then all B, phi_d fastest.
Physical value = raw * scale with scale = (1/1500, 1.15/1500, 1.66/1500).
A negative raw value marks an unmeasured bin.

Bad input policy (every case raises :class:`MerlFormatError` naming the source):

- empty, shorter than the header, text instead of binary, header dims that are
  zero, negative, absurd or not (90, 90, 180), a body shorter (truncated) or
  longer (trailing bytes) than the header promises: refused *before* the body
  is allocated, from the file size alone;
- a table with no measured bin: refused;
- values outside the physical range (:data:`MAX_VALUE`, :data:`MIN_PEAK`): refused,
  the message naming how many bins and the extreme value. A bin above 1e12 1/sr is
  a corrupt value or another unit, not a reflectance, and one such bin would
  dominate every error metric; a table whose brightest bin is below 1e-5 1/sr
  (all zeros, all denormals) holds nothing a fit could recover.
- NaN / Inf values: **masked, not refused**, and counted in
  :attr:`MerlTable.n_nonfinite` (real captures do contain a few). A bin is
  measured only when all three channels are finite and >= 0.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from brdffit.errors import MerlFormatError
from brdffit.io import atomic
from brdffit.io.angles import (
    N_PHI_D,
    N_THETA_D,
    N_THETA_H,
    SHAPE,
    dirs_to_half_diff,
    half_diff_to_bins,
)
from brdffit.io.buffers import aligned_empty

SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
HEADER_BYTES = 12
N_BINS = N_THETA_H * N_THETA_D * N_PHI_D
FILE_BYTES = HEADER_BYTES + 3 * N_BINS * 8  # 34,992,012

#: Largest physical value (1/sr) a table may hold. Measured MERL tables peak near
#: 1e4 1/sr; the sharpest lobe the models allow (GGX or Beckmann, alpha 1e-3, ks 1)
#: reaches 1e9 1/sr in the grazing bins of the mirror direction (its 1/(4 cos_i
#: cos_o)). 1e12 leaves room above both and keeps the float32 full-table error
#: (``brdffit.fitting.pipeline``) clear of overflow: (1e12)^2 = 1e24 < 3e38.
MAX_VALUE = 1e12
#: Smallest brightest-bin value (1/sr) of a table: the blackest coatings made
#: (~0.04% reflectance) are near 1e-4 1/sr. Below this a table is blank (all
#: zeros, all denormals) or in the wrong unit, and a fit of it is noise.
MIN_PEAK = 1e-5


#: :meth:`MerlTable.isolated_spikes`: a bin this many times every measured neighbour.
SPIKE_FACTOR = 1000.0
#: More bins than this above SPIKE_FACTOR times the table's typical value are a broad
#: bright region, not a few corrupt values: the check leaves such a table alone.
MAX_SPIKE_CANDIDATES = 100_000


@dataclass(frozen=True, eq=False)
class MerlTable:
    """A measured isotropic BRDF on the MERL grid.

    ``rgb``: physical values (1/sr), shape (3, 90, 90, 180), 0 where unmeasured.
    ``mask``: True where a bin is measured (all channels finite and >= 0).
    ``n_partial``: unmeasured bins with some channels >= 0, all finite: MERL marks an
    unmeasured bin negative in every channel, so such bins are more likely noise
    around zero (a dark frame subtracted), left out whole all the same (the fit says so).
    """

    rgb: np.ndarray
    mask: np.ndarray
    source: str = "<memory>"
    n_nonfinite: int = 0
    n_partial: int = 0

    def __post_init__(self):
        """The arrays checked and made read-only. A fit keeps what it derives from a
        table (its subsample, device copy, renders) with the table object: a table
        changed in place was fitted again from the old values, with an error measured
        on the new ones. Arrays given writable are copied (the caller's stay theirs); to
        change a table, make a new one (``MerlTable.from_values(t.rgb * 2, t.mask)``).
        Arrays given read-only are taken as they are (the readers' own)."""
        rgb, mask = self.rgb, self.mask
        trusted = (isinstance(rgb, np.ndarray) and isinstance(mask, np.ndarray)
                   and not rgb.flags.writeable and not mask.flags.writeable
                   and rgb.dtype == np.float64 and mask.dtype == bool
                   and rgb.shape == (3, *SHAPE) and mask.shape == SHAPE)
        if not trusted:
            rgb, mask = _checked_arrays(rgb, mask, self.source)
            object.__setattr__(self, "rgb", rgb)
            object.__setattr__(self, "mask", mask)

    @classmethod
    def from_values(cls, rgb, mask=None, source: str = "<memory>") -> MerlTable:
        """A table from physical values; bins that are negative or non-finite are masked."""
        rgb = _merl_layout(rgb, source)
        channel_ok = np.isfinite(rgb) & (rgb >= 0)
        ok = np.all(channel_ok, axis=0)
        n_partial = int(np.count_nonzero(~ok & np.any(channel_ok, axis=0)
                                         & np.all(np.isfinite(rgb), axis=0)))
        n_nonfinite = int(np.count_nonzero(~np.all(np.isfinite(rgb), axis=0)))
        if mask is not None:
            ok &= np.asarray(mask, dtype=bool).reshape(SHAPE)
        if not ok.any():
            raise MerlFormatError(source, "no measured bin: every value is negative, "
                                          "non-finite or masked")
        rgb = np.where(ok, rgb, 0.0)
        _check_range(rgb, source)
        return cls(_read_only(rgb), _read_only(ok), source, n_nonfinite, n_partial=n_partial)

    @property
    def n_measured(self) -> int:
        return int(np.count_nonzero(self.mask))

    def isolated_spikes(self) -> np.ndarray:
        """Measured bins over :data:`SPIKE_FACTOR` times every measured grid neighbour
        (theta_h, theta_d and phi_d +-1; phi_d wraps, as reciprocity makes it), each by
        its brightest channel: indices (k, 3) into the grid, brightest first. A reflectance changes
        by less than that from one bin to the next, even at a mirror's peak; one such
        bin is a corrupt value, which a least-squares fit follows (a bin at 9e11 1/sr
        made a ggx of ks 1e6). Only bins above SPIKE_FACTOR times the table's typical
        value (the median of a sample of its measured values) are looked at."""
        rgb, mask = self.rgb, self.mask
        flat = rgb.reshape(3, -1)
        sample = flat[:, ::97][:, mask.ravel()[::97]]
        typical = float(np.median(sample)) if sample.size else 0.0
        bright = flat.max(axis=0) > SPIKE_FACTOR * typical
        cand = np.argwhere(mask & bright.reshape(mask.shape))
        if cand.size == 0 or cand.shape[0] > MAX_SPIKE_CANDIDATES:
            return np.zeros((0, 3), np.int64)
        th, td, pd = cand.T
        neighbour = np.full((3, cand.shape[0]), -np.inf)
        for i, j, k in ((th - 1, td, pd), (th + 1, td, pd), (th, td - 1, pd),
                        (th, td + 1, pd), (th, td, (pd - 1) % N_PHI_D),
                        (th, td, (pd + 1) % N_PHI_D)):
            inside = (i >= 0) & (i < N_THETA_H) & (j >= 0) & (j < N_THETA_D)
            i, j = np.clip(i, 0, N_THETA_H - 1), np.clip(j, 0, N_THETA_D - 1)
            seen = inside & mask[i, j, k]
            neighbour = np.maximum(neighbour, np.where(seen, rgb[:, i, j, k], -np.inf))
        # by each one's brightest channel: a noisy sparse table's true peak (317 1/sr)
        # beside a neighbour whose one channel noise had clipped to 0 (249, 0, 339) read
        # as a corrupt spike "over 1,000x" that 0; a corrupt channel is still its bin's
        # brightest by far
        value = rgb[:, th, td, pd].max(axis=0)
        spike = (np.isfinite(neighbour).any(axis=0)
                 & (value > SPIKE_FACTOR * np.maximum(neighbour.max(axis=0), 0.0)))
        out = cand[spike]
        return out[np.argsort(-rgb[:, out[:, 0], out[:, 1], out[:, 2]].max(axis=0),
                              kind="stable")]

    def lookup(self, wi, wo) -> np.ndarray:
        """Nearest-bin values at direction pairs (..., 3) -> (..., 3); NaN where unmeasured."""
        i_th, i_td, i_pd = half_diff_to_bins(*dirs_to_half_diff(np.asarray(wi), np.asarray(wo)))
        vals = self.rgb[:, i_th, i_td, i_pd]
        vals = np.where(self.mask[i_th, i_td, i_pd], vals, np.nan)
        return np.moveaxis(vals, 0, -1)

    def summary(self) -> dict:
        """Plain-JSON description: bin counts and per-channel value ranges."""
        measured = self.rgb[:, self.mask]
        return {
            "source": self.source,
            "measured_bins": self.n_measured,
            "unmeasured_bins": N_BINS - self.n_measured,
            "nonfinite_bins": self.n_nonfinite,
            "min": measured.min(axis=1).tolist(),
            "median": np.median(measured, axis=1).tolist(),
            "max": measured.max(axis=1).tolist(),
        }


def looks_like_text(head: bytes) -> bool:
    return len(head) > 0 and all(32 <= b < 127 or b in (9, 10, 13) for b in head)


#: The first bytes of files people mistake for a table, and what they are.
OTHER_FORMATS = (
    (b"\x89PNG", "a PNG image"), (b"\xff\xd8\xff", "a JPEG image"), (b"GIF8", "a GIF image"),
    (b"II*\x00", "a TIFF image"), (b"MM\x00*", "a TIFF image"),
    (b"\x76\x2f\x31\x01", "an OpenEXR image"), (b"\x1f\x8b", "a gzip archive"),
    (b"PK\x03\x04", "a zip archive"), (b"%PDF", "a PDF document"),
    (b"\x93NUMPY", "a numpy .npy array (one array, unnamed: np.savez names them)"),
    (b"\x89HDF", "an HDF5 file"),
    (b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1", "an OLE2 document (an Excel 97-2003 .xls workbook? "
                                         "save it as .xlsx or CSV)"),
    # 11 bytes: the magic is held within the 12-byte header it is judged by
    (b"MATLAB 5.0 ", "a MATLAB .mat file (a sample list: brdffit fit reads it)"),
)


def other_format(head: bytes) -> str | None:
    """What a file of these first bytes is, where :data:`OTHER_FORMATS` knows it (a
    PNG image, a zip archive, ...), else None."""
    return next((what for magic, what in OTHER_FORMATS if head.startswith(magic)), None)


def _check_layout(header: bytes, size: int, source: str) -> None:
    """Validate header and total size; raises before anything large is allocated."""
    if size == 0:
        raise MerlFormatError(source, "empty file; a MERL table is 34,992,012 bytes")
    if size < HEADER_BYTES:
        raise MerlFormatError(source, f"only {size} bytes, shorter than the 12-byte header")
    kind = other_format(header)
    if kind is not None:  # before the text test: a PDF's and a .mat file's start is text
        hint = " (decompress it first)" if kind == "a gzip archive" else ""
        raise MerlFormatError(source, f"{kind}, not a binary MERL table (by its first "
                                      f"bytes){hint}")
    if looks_like_text(header):
        raise MerlFormatError(source, "looks like a text file, not a binary MERL table")
    dims = [int(d) for d in np.frombuffer(header, dtype="<i4", count=3)]
    if tuple(int(d) for d in np.frombuffer(header, dtype=">i4", count=3)) == SHAPE:
        raise MerlFormatError(
            source, f"header dims {dims} read little-endian, as MERL writes them, are "
                    f"{list(SHAPE)} big-endian: the file was written byte-swapped; swap "
                    "its 4-byte header and 8-byte values to little-endian")
    if any(d <= 0 for d in dims):
        raise MerlFormatError(source, f"header dims {dims} are not positive: not a MERL "
                                      f"table (it starts with 3 dims, {list(SHAPE)})")
    body = size - HEADER_BYTES
    expected = 3 * 8 * dims[0] * dims[1] * dims[2]  # Python ints: no overflow
    if tuple(dims) != SHAPE:
        raise MerlFormatError(
            source,
            f"header dims {dims} are not the MERL grid {list(SHAPE)}"
            + (
                f" (they would need {expected:,} bytes, the file has {body:,})"
                if expected != body
                else ""
            ),
        )
    if body < expected:
        # exactly half: the values written as float32 (a MERL table holds float64), as
        # a converter that kept numpy's float32 writes them; not read as if they were
        half = (" (exactly half: values written as float32? a MERL table holds float64; "
                "convert them, e.g. numpy's astype('<f8'))" if 2 * body == expected else "")
        raise MerlFormatError(
            source, f"truncated: body has {body:,} bytes, the header promises {expected:,}"
            + half
        )
    if body > expected:
        raise MerlFormatError(
            source, f"{body - expected:,} trailing bytes after the {expected:,}-byte body"
        )


def _check_range(rgb: np.ndarray, source: str, raw: np.ndarray | None = None,
                 measured: np.ndarray | None = None) -> None:
    """Refuse physical values ``rgb`` (0 where unmeasured) outside MAX_VALUE / MIN_PEAK.

    ``raw`` and ``measured``, the file's values and its measured bins, let the
    message quote what the file holds: raw 5e-324 is 0 1/sr once scaled."""
    peak = float(rgb.max())  # one pass; the details are worked out only to refuse
    if peak > MAX_VALUE:
        n = int(np.count_nonzero((rgb > MAX_VALUE).any(axis=0)))
        c = np.unravel_index(int(np.argmax(rgb)), rgb.shape)[0]
        raise MerlFormatError(
            source,
            f"{n:,} bin{'s' if n != 1 else ''} above {MAX_VALUE:g} 1/sr, the largest "
            f"{peak:.3g} 1/sr (raw {peak / SCALE[c]:.3g}); measured BRDFs peak near 1e4 "
            "1/sr: a corrupt file, or values in another unit",
        )
    if peak < MIN_PEAK:
        raw_peak = ""
        if raw is not None:
            raw_peak = f" (largest raw value {float(raw[:, measured].max()):.3g})"
        raise MerlFormatError(source, too_dark(f"measured bin is {peak:.3g} 1/sr{raw_peak}",
                                               "table"))


def too_dark(brightest: str, blank: str) -> str:
    """Why values whose brightest (``brightest``: "measured bin is 0 1/sr") is below
    :data:`MIN_PEAK` are refused; ``blank``: what they are, a "table" or a "list"."""
    return (f"the brightest {brightest}, below {MIN_PEAK:g} 1/sr and darker than any "
            f"material: a blank {blank} (zeros, denormals) or values in another unit; there "
            "is no reflectance to fit")


#: The bits of +inf: as unsigned integers, every IEEE double at or above this is
#: NaN, infinite or negative (sign bit set), and every one below it is finite and >= 0.
_INF_BITS = np.uint64(0x7FF0000000000000)
#: The sign bit: without it, a value's bits are at or above ``_INF_BITS`` exactly where it
#: is NaN or infinite.
_SIGN_BIT = np.uint64(0x8000000000000000)


def _from_raw(raw: np.ndarray, source: str) -> MerlTable:
    """Raw file values -> physical values and mask, converted in place in ``raw``
    (which must be writable and not shared): a few passes over 35 MB and no
    second 35 MB array, so that reading runs near the speed of the disk cache.

    The tests work on the values' bits (see ``_INF_BITS``): a bin is measured when
    the largest of its three channels' bit patterns, read as unsigned integers, is
    below +inf's, one pass instead of a minimum, a maximum and their comparisons.
    A negative zero is a measured zero (``-0.0 >= 0``: rounding a small negative
    noise writes one, ``np.round(-1e-9, 6)``), made ``+0.0``; its sign bit alone had
    made its bin unmeasured.
    """
    raw = raw.reshape(3, -1)
    bits = raw.view(np.uint64)
    top = np.maximum(bits[0], bits[1])
    np.maximum(top, bits[2], out=top)
    unmeasured = top >= _INF_BITS
    _measured_zeros(raw, bits, unmeasured)
    # of those, the bins with a channel finite and >= 0 and none NaN or infinite (a few
    # ms: only the unmeasured bins are looked at again); a bin with an infinite channel
    # is a non-finite one, not "negative in some channels" (every 7th value +inf read as
    # 43% of the bins partly negative)
    low = np.minimum(bits[0][unmeasured], bits[1][unmeasured])
    some_ok = np.minimum(low, bits[2][unmeasured]) < _INF_BITS
    magnitude = [b[unmeasured] & ~_SIGN_BIT for b in bits]
    all_finite = np.maximum(np.maximum(magnitude[0], magnitude[1]), magnitude[2]) < _INF_BITS
    n_partial = int(np.count_nonzero(some_ok & all_finite))
    if unmeasured.all():
        # one channel never measured makes every bin unmeasured: say which
        dead = [c for c, b in zip("RGB", bits, strict=True) if bool((b >= _INF_BITS).all())]
        raise MerlFormatError(
            source, "no measured bin: every value is negative or non-finite"
            if len(dead) == 3 else
            f"no measured bin: channel {' and '.join(dead)} is negative or non-finite in "
            "every bin (a bin is measured where all three channels are)"
            if dead else "no measured bin: every bin has a negative or non-finite channel")
    # bins with a NaN or infinite channel (np.isfinite per channel: ~4x faster than
    # masking the bits' magnitudes)
    finite = np.isfinite(raw[0])
    finite &= np.isfinite(raw[1])
    finite &= np.isfinite(raw[2])
    n_nonfinite = int(finite.size - np.count_nonzero(finite))
    np.copyto(raw, 0.0, where=unmeasured)
    rgb, measured = raw.reshape(3, *SHAPE), ~unmeasured.reshape(SHAPE)
    # scaling is monotonic: the physical peak is the largest raw channel peak scaled
    peak = float((raw.max(axis=1) * SCALE).max())
    if not MIN_PEAK <= peak <= MAX_VALUE:  # refused: the message quotes the file's values
        _check_range(rgb * SCALE[:, None, None, None], source, raw=rgb, measured=measured)
    for c in range(3):
        raw[c] *= SCALE[c]
    return MerlTable(_read_only(rgb), _read_only(measured), source, n_nonfinite,
                     n_partial=n_partial)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _merl_layout(rgb, source: str) -> np.ndarray:
    """``rgb`` as float64 of shape (3, 90, 90, 180): given so, or flat in that order
    (a .binary file's body). Any other shape of as many values is refused: channels
    last, (90, 90, 180, 3), reshaped, was fitted as a scramble, "successful"."""
    a = np.asarray(rgb)
    if a.dtype.kind not in "biuf":
        raise MerlFormatError(source, f"rgb holds {a.dtype} values, not real numbers")
    if a.shape not in ((3, *SHAPE), (3 * N_BINS,), (3, N_BINS)):
        hint = (" (channels last: np.moveaxis(rgb, -1, 0))"
                if a.shape == (*SHAPE, 3) else "")
        raise MerlFormatError(source, f"rgb of shape {a.shape}: a MERL table's values are "
                                      f"(3, {', '.join(map(str, SHAPE))}), channel first, or "
                                      f"flat in that order{hint}")
    return a.astype(np.float64, copy=False).reshape(3, *SHAPE)


def _checked_arrays(rgb, mask, source: str) -> tuple[np.ndarray, np.ndarray]:
    """A table's arrays given to :class:`MerlTable` directly, checked as the readers'
    are and copied read-only: a mask of booleans (or of 0 and 1), measured bins finite
    and >= 0, unmeasured ones 0 (NaN there made a good fit read "nonfinite")."""
    rgb = np.array(_merl_layout(rgb, source), dtype=np.float64)  # a copy of its own
    m = np.asarray(mask)
    if m.shape != SHAPE:
        raise MerlFormatError(source, f"mask of shape {m.shape}: a MERL table's is {SHAPE}")
    if m.dtype != bool:
        if m.dtype.kind not in "biuf" or not np.isin(m, (0, 1)).all():
            raise MerlFormatError(source, f"mask of {m.dtype} values other than 0 and 1: "
                                          "a mask is True where a bin is measured")
    m = np.array(m, dtype=bool)
    measured = rgb[:, m]
    if not (np.isfinite(measured).all() and (measured >= 0).all()):
        raise MerlFormatError(source, "a measured bin (mask True) holds a negative or "
                                      "non-finite value: MerlTable.from_values(rgb) masks "
                                      "such bins itself")
    rgb[:, ~m] = 0.0
    return _read_only(rgb), _read_only(m)


def _measured_zeros(raw: np.ndarray, bits: np.ndarray, unmeasured: np.ndarray) -> None:
    """The bins of ``unmeasured`` whose channels are finite and >= 0 once a negative
    zero counts as 0, made measured, their negative zeros ``+0.0`` (in place). Only
    the unmeasured bins are looked at: a negative zero's bits are above ``_INF_BITS``."""
    where = np.flatnonzero(unmeasured)
    held = bits[:, where]
    zeros = held == _SIGN_BIT
    if not zeros.any():
        return
    ok = ((held < _INF_BITS) | zeros).all(axis=0)
    for c in range(3):
        raw[c, where[ok & zeros[c]]] = 0.0
    unmeasured[where[ok]] = False


def _aligned_values() -> np.ndarray:
    """An uninitialised little-endian float64 array for a table's 3 x N_BINS values,
    64-byte aligned (``brdffit.io.buffers``), so that the fits' full-table passes
    read the table where it lies instead of copying 35 MB per table."""
    return aligned_empty(3 * N_BINS, "<f8")


def read(path: str | os.PathLike) -> MerlTable:
    """Read a MERL ``.binary`` file. Raises :class:`MerlFormatError` on any bad file."""
    source = os.fspath(path)
    try:
        with open(source, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            header = f.read(HEADER_BYTES)
            _check_layout(header, size, source)
            raw = _aligned_values()
            n_read = f.readinto(memoryview(raw).cast("B"))
    except IsADirectoryError:
        raise MerlFormatError(source, "is a directory, not a MERL table") from None
    except OSError as e:
        raise MerlFormatError(source, f"cannot read: {e.strerror or e}") from None
    if n_read != raw.nbytes:  # file shrank between stat and read
        raise MerlFormatError(source, "truncated while reading")
    return _from_raw(raw, source)


def from_bytes(data: bytes, source: str = "<bytes>") -> MerlTable:
    """Parse a MERL table held in memory (an upload); same checks as :func:`read`."""
    _check_layout(bytes(data[:HEADER_BYTES]), len(data), source)
    raw = _aligned_values()  # converted in place: not in the caller's buffer
    raw[:] = np.frombuffer(data, dtype="<f8", count=3 * N_BINS, offset=HEADER_BYTES)
    return _from_raw(raw, source)


def to_bytes(table: MerlTable) -> bytes:
    """The file image of ``table``; unmeasured bins are written as raw -1."""
    raw = np.where(table.mask, table.rgb / SCALE[:, None, None, None], -1.0)
    header = np.asarray(SHAPE, dtype="<i4").tobytes()
    return header + np.ascontiguousarray(raw, dtype="<f8").tobytes()


def write(path: str | os.PathLike, table: MerlTable) -> None:
    """Write ``table`` as a MERL file, atomically (temp file + rename), with the
    permissions ``open`` would give it: a table is data to share (cluster workers may
    run as another user)."""
    atomic.write_bytes(path, to_bytes(table), prefix=".merl-")
