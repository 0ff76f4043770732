"""MERL reader/writer: round trips and every malformed-file case, with its message."""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest

from brdffit.errors import MerlFormatError
from brdffit.io import merl

pytestmark = pytest.mark.unit

N = merl.N_BINS


def _raw_file(path, dims=(90, 90, 180), body=None, n_values=3 * N):
    if body is None:
        body = np.full(n_values, 150.0)
    path.write_bytes(struct.pack("<3i", *dims) + np.asarray(body, "<f8").tobytes())
    return path


@pytest.fixture(scope="module")
def good_raw():
    rng = np.random.default_rng(1)
    raw = rng.uniform(0, 3000, 3 * N)
    raw[rng.random(3 * N) < 0.1] = -1.0
    return raw


def test_round_trip_is_exact(tmp_path, good_raw):
    p = _raw_file(tmp_path / "a.binary", body=good_raw)
    t = merl.read(p)
    assert t.rgb.shape == (3, 90, 90, 180) and t.mask.shape == (90, 90, 180)
    merl.write(tmp_path / "b.binary", t)
    t2 = merl.read(tmp_path / "b.binary")
    np.testing.assert_array_equal(t.mask, t2.mask)
    np.testing.assert_allclose(t.rgb, t2.rgb, rtol=1e-15)
    assert (tmp_path / "b.binary").stat().st_size == merl.FILE_BYTES == 12 + 34_992_000


def test_values_scaled_and_channel_major(tmp_path):
    body = np.zeros(3 * N)
    body[:N], body[N : 2 * N], body[2 * N :] = 1500.0, 1500.0, 1500.0
    # one recognisable bin: i_th=2, i_td=3, i_pd=4 in the R channel
    ind = 4 + 180 * 3 + 180 * 90 * 2
    body[ind] = 3000.0
    t = merl.read(_raw_file(tmp_path / "s.binary", body=body))
    np.testing.assert_allclose(t.rgb[:, 0, 0, 0], [1.0, 1.15, 1.66])
    assert t.rgb[0, 2, 3, 4] == pytest.approx(2.0)


def test_negative_values_are_unmeasured(tmp_path, good_raw):
    t = merl.read(_raw_file(tmp_path / "a.binary", body=good_raw))
    neg = np.any(good_raw.reshape(3, 90, 90, 180) < 0, axis=0)
    np.testing.assert_array_equal(t.mask, ~neg)
    assert np.all(t.rgb[:, ~t.mask] == 0)
    # bins negative in some channels only (noise around zero, not MERL's marker) are
    # counted, by the reader and from values alike: the fit says what leaving them cost
    rows = good_raw.reshape(3, -1) < 0
    partial = int(np.count_nonzero(rows.any(axis=0) & ~rows.all(axis=0)))
    assert t.n_partial == partial > 0
    assert merl.MerlTable.from_values(good_raw.reshape(3, -1)).n_partial == partial
    marked = np.where(rows.any(axis=0), -1.0, good_raw.reshape(3, -1))  # every channel
    assert merl.read(_raw_file(tmp_path / "m.binary", body=marked.ravel())).n_partial == 0


def test_a_negative_zero_is_a_measured_zero(tmp_path, good_raw):
    """-0.0 >= 0 (rounding a small negative noise writes it): its bin is measured, as
    a sample list's and ``from_values`` keep it; its sign bit alone made half of a
    table whose zeros were written so unmeasured. -1, MERL's marker, still is."""
    body = good_raw.copy().reshape(3, -1)
    measured = (body >= 0).all(axis=0)
    some = np.flatnonzero(measured)[::3]
    body[0, some] = -0.0  # one channel
    body[:, some[::2]] = -0.0  # every channel
    t = merl.read(_raw_file(tmp_path / "z.binary", body=body.ravel()))
    np.testing.assert_array_equal(t.mask.ravel(), measured)
    assert not np.signbit(t.rgb).any() and np.all(t.rgb.reshape(3, -1)[0, some] == 0.0)
    assert t.n_partial == merl.read(_raw_file(tmp_path / "a.binary", body=good_raw)).n_partial
    np.testing.assert_array_equal(merl.MerlTable.from_values(body).mask.ravel(), measured)


def test_nonfinite_values_are_masked_and_counted(tmp_path):
    body = np.full(3 * N, 100.0)
    body[[0, 5, N + 7]] = [np.nan, np.inf, -np.inf]
    t = merl.read(_raw_file(tmp_path / "n.binary", body=body))
    assert t.n_nonfinite == 3
    # a bin with a NaN or infinite channel is non-finite, not "negative in some channels"
    # (every 7th value +inf read as 43% of the bins partly negative), read or given
    body[N + 9] = -1.0  # one bin negative in one channel: that one is partial
    assert merl.read(_raw_file(tmp_path / "p.binary", body=body)).n_partial == 1
    assert merl.MerlTable.from_values(body.reshape(3, -1)).n_partial == 1
    assert t.n_measured == N - 3
    assert np.all(np.isfinite(t.rgb))
    assert t.summary()["nonfinite_bins"] == 3


def test_from_bytes_matches_read(tmp_path, good_raw):
    p = _raw_file(tmp_path / "a.binary", body=good_raw)
    a, b = merl.read(p), merl.from_bytes(p.read_bytes(), "upload")
    np.testing.assert_array_equal(a.rgb, b.rgb)


@pytest.mark.parametrize(
    "name, make, message",
    [
        ("empty", lambda p: p.write_bytes(b""), "empty file"),
        ("short", lambda p: p.write_bytes(b"\x5a\x00\x00"), "shorter than the 12-byte header"),
        ("text", lambda p: p.write_text("theta_h,theta_d,phi_d,r,g,b\n0,0,0,1,1,1\n"), "text file"),
        ("truncated", lambda p: _raw_file(p, n_values=3 * N - 10), "truncated"),
        (
            "trailing",
            lambda p: p.write_bytes(
                struct.pack("<3i", 90, 90, 180) + np.zeros(3 * N + 1).tobytes()
            ),
            "trailing bytes",
        ),
        ("negative dims", lambda p: _raw_file(p, dims=(90, -90, 180), n_values=10), "not positive"),
        ("zero dims", lambda p: _raw_file(p, dims=(0, 90, 180), n_values=10), "not positive"),
        (
            "wrong dims",
            lambda p: _raw_file(p, dims=(45, 90, 180), n_values=3 * 45 * 90 * 180),
            "not the MERL grid",
        ),
        (
            "absurd dims",
            lambda p: _raw_file(p, dims=(2**30, 2**30, 2**30), n_values=10),
            "not the MERL grid",
        ),
        # what people mistake for a table is named (its header read as dims was a
        # number of 10^26 bytes), and a byte-swapped table is told so
        ("png", lambda p: p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200)),
         "a PNG image, not a binary MERL table"),
        ("exr", lambda p: p.write_bytes(b"\x76\x2f\x31\x01" + bytes(200)), "an OpenEXR image"),
        ("big-endian", lambda p: p.write_bytes(struct.pack(">3i", 90, 90, 180)
                                               + np.ones(30).astype(">f8").tobytes()),
         "are [90, 90, 180] big-endian: the file was written byte-swapped"),
        # a converter that kept float32: named, not read as a truncated float64 body
        ("float32", lambda p: p.write_bytes(struct.pack("<3i", 90, 90, 180)
                                            + np.ones(3 * N, "<f4").tobytes()),
         "exactly half: values written as float32? a MERL table holds float64"),
        ("no measured bin", lambda p: _raw_file(p, body=np.full(3 * N, -1.0)), "no measured bin"),
        ("all nan", lambda p: _raw_file(p, body=np.full(3 * N, np.nan)), "no measured bin"),
        ("one channel never measured",
         lambda p: _raw_file(p, body=np.concatenate([np.ones(N), np.full(N, -1.0), np.ones(N)])),
         "no measured bin: channel G is negative or non-finite in every bin"),
    ],
)
def test_malformed_files_raise_clear_errors(tmp_path, name, make, message):
    p = tmp_path / "bad.binary"
    make(p)
    with pytest.raises(MerlFormatError) as e:
        merl.read(p)
    assert message in str(e.value)
    assert str(p) in str(e.value)
    if p.stat().st_size >= 12:  # same verdict for an upload of the same bytes
        with pytest.raises(MerlFormatError, match=re.escape(message)):
            merl.from_bytes(p.read_bytes(), "upload")


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(MerlFormatError, match="cannot read"):
        merl.read(tmp_path / "nope.binary")
    with pytest.raises(MerlFormatError, match="directory"):
        merl.read(tmp_path)


def test_absurd_dims_do_not_allocate(tmp_path, monkeypatch):
    """The size check happens before any body read: fromfile must never be called."""
    p = _raw_file(tmp_path / "huge.binary", dims=(90, 90, 180), n_values=10)
    monkeypatch.setattr(np, "fromfile", lambda *a, **k: pytest.fail("body was read"))
    with pytest.raises(MerlFormatError, match="truncated"):
        merl.read(p)


def test_format_error_survives_pickling():
    """Worker processes (service, batch, Dask) send errors back pickled."""
    import pickle

    e = pickle.loads(pickle.dumps(MerlFormatError("a.binary", "truncated")))
    assert isinstance(e, MerlFormatError) and str(e) == "a.binary: truncated"
    assert e.source == "a.binary" and e.problem == "truncated"


def test_written_tables_respect_the_umask(tmp_path, good_raw):
    import os
    import stat

    t = merl.read(_raw_file(tmp_path / "a.binary", body=good_raw))
    old = os.umask(0o022)
    try:
        merl.write(tmp_path / "b.binary", t)
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "b.binary").stat().st_mode) == 0o644


def test_a_table_cannot_be_changed_in_place_and_arrays_given_by_hand_are_checked():
    """What a library review found: a table changed in place (t.rgb *= 2) was fitted
    again from the old values (a fit keeps what it derives with the table object); a
    channels-last array was reshaped into a scramble and fitted "successful"; NaN in
    unmeasured bins made a good fit "nonfinite"; an int mask failed deep in the fit."""
    from brdffit import fit
    from data_synth import make_table

    table = make_table("lambert", {"kd": [0.5, 0.3, 0.2]})[0]
    with pytest.raises(ValueError, match="read-only"):
        table.rgb[...] *= 2
    doubled = fit(merl.MerlTable.from_values(table.rgb * 2, table.mask), "lambert")
    np.testing.assert_allclose(doubled.params["kd"], [1.0, 0.6, 0.4], rtol=1e-3)
    # arrays given writable are copied: the caller's stay theirs, the table's do not move
    rgb, mask = np.array(table.rgb), np.array(table.mask)
    mine = merl.MerlTable(rgb, mask)
    rgb *= 3
    assert mine.rgb.max() == table.rgb.max() and not mine.rgb.flags.writeable
    with pytest.raises(MerlFormatError, match=r"channels last: np.moveaxis\(rgb, -1, 0\)"):
        merl.MerlTable.from_values(np.moveaxis(table.rgb, 0, -1))
    with pytest.raises(MerlFormatError, match=r"rgb of shape \(90, 90, 180, 3\)"):
        merl.MerlTable(np.moveaxis(table.rgb, 0, -1), table.mask)
    # NaN where unmeasured is 0 in the table; an int mask of 0/1 is a mask
    nan_unmeasured = np.where(table.mask, table.rgb, np.nan)
    by_hand = merl.MerlTable(nan_unmeasured, table.mask.astype(np.int8))
    assert by_hand.mask.dtype == bool and np.all(by_hand.rgb[:, ~by_hand.mask] == 0)
    r = fit(by_hand, "lambert")
    assert r.result == "successful" and np.isfinite(r.error["log_rmse"])
    with pytest.raises(MerlFormatError, match="a measured bin .mask True. holds a negative"):
        merl.MerlTable(np.where(table.mask, -1.0, 0.0) * np.ones((3, 1, 1, 1)), table.mask)
    with pytest.raises(MerlFormatError, match="values other than 0 and 1"):
        merl.MerlTable(table.rgb, table.mask.astype(float) * 2)
