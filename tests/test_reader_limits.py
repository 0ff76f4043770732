"""What the sample readers refuse of files no lab writes, in one line and at once: a
workbook that declares cells far beyond its samples, arrays of dates, half and
difference angles out of their range, a unit attribute of bytes that are no text."""

from __future__ import annotations

import re
import time
import zipfile

import numpy as np
import pytest

from brdffit.io import workbook
from brdffit.io.measurements import MeasurementsError
from brdffit.io.readers import read_measured

pytestmark = pytest.mark.unit

HEAD = ["theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b"]


def _rows(n: int = 40, seed: int = 0) -> list[list[float]]:
    rng = np.random.default_rng(seed)
    return [[float(x) for x in (*rng.uniform(0, 80, 1), *rng.uniform(0, 360, 1),
                                *rng.uniform(0, 80, 1), *rng.uniform(0, 360, 1),
                                *rng.uniform(0.05, 2.0, 3))] for _ in range(n)]


def _book(path, rows, far: tuple[int, int] | None = None):
    import openpyxl

    wb = openpyxl.Workbook()
    for row in rows:
        wb.active.append(row)
    if far is not None:
        wb.active.cell(row=far[0], column=far[1], value=1)
    wb.save(path)
    return path


def _sheet_xml(path, edit) -> None:
    """The workbook ``path`` with its first sheet's XML passed through ``edit``."""
    with zipfile.ZipFile(path) as z:
        parts = {i: z.read(i) for i in z.infolist()}
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for info, data in parts.items():
            z.writestr(info, edit(data) if info.filename == "xl/worksheets/sheet1.xml"
                       else data)


@pytest.mark.parametrize("far, said", [
    ((1_048_576, 16_384), "declares cells up to XFD1048576 .1,048,576 rows of 16,384 "
                          "columns.: more than a sample list's .10,000 columns."),
    ((5_000, 16_384), "declares cells up to XFD5000 .5,000 rows of 16,384 columns.: more "
                      "than a sample list's .10,000 columns."),
    ((1_000_000, 60), "declares cells up to BH1000000 .1,000,000 rows of 60 columns.: more "
                      "than a sample list's .50,000,000 cells."),
])
def test_a_sheet_declaring_cells_far_beyond_its_samples_is_refused_before_a_row_is_read(
        tmp_path, far, said):
    """A 5 KB workbook with one cell at XFD1048576 hung the reader (openpyxl gives every
    row as wide as the sheet: 16,384 cells each, a million rows); one at XFD5000 took
    11 s. Refused from the sheet's declared range, saying it and the limit."""
    path = _book(tmp_path / "far.xlsx", [HEAD, *_rows()], far)
    start = time.perf_counter()
    with pytest.raises(MeasurementsError, match=f"far.xlsx: sheet 'Sheet' {said}; clear the "
                                                "cells beyond its samples"):
        read_measured(path)
    assert time.perf_counter() - start < 5


def test_a_sheet_without_its_declared_range_is_weighed_row_by_row(tmp_path, monkeypatch):
    """A sheet whose XML declares no range (or one too small) is read as far as its
    cells reach: a far cell is refused at its row, and so are more cells than a sample
    list's; a sheet whose record says less than it holds is read whole (openpyxl cut its
    rows to the record's range, unsaid)."""
    rows = _rows()
    no_range = _book(tmp_path / "no_range.xlsx", [HEAD, *rows], far=(5, 16_384))
    _sheet_xml(no_range, lambda xml: re.sub(rb"<dimension [^>]*/>", b"", xml))
    start = time.perf_counter()
    with pytest.raises(MeasurementsError, match="sheet 'Sheet' row 5 reaches column XFD "
                                                ".16,384 columns.: more than a sample "
                                                "list's .10,000 columns."):
        read_measured(no_range)
    assert time.perf_counter() - start < 5

    plain = _book(tmp_path / "plain.xlsx", [HEAD, *rows])
    want = read_measured(plain)
    short = _book(tmp_path / "short.xlsx", [HEAD, *rows])
    _sheet_xml(short, lambda xml: re.sub(rb'<dimension ref="[^"]*"', b'<dimension ref="A1:B2"',
                                         xml))
    for path in (short, plain):
        got = read_measured(path)
        np.testing.assert_array_equal(got.rgb, want.rgb)
        np.testing.assert_array_equal(got.wi, want.wi)
        assert got.n == len(rows)

    monkeypatch.setattr(workbook, "MAX_CELLS", 7 * 20)  # 20 rows of 7 cells
    _sheet_xml(plain, lambda xml: re.sub(rb"<dimension [^>]*/>", b"", xml))
    with pytest.raises(MeasurementsError, match="sheet 'Sheet' rows 1 to 21 span 147 cells: "
                                                "more than a sample list's .140 cells."):
        read_measured(plain)


def _angles(n: int = 200) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(3)
    return {"theta_i_deg": rng.uniform(0, 80, n), "phi_i_deg": rng.uniform(0, 360, n),
            "theta_o_deg": rng.uniform(0, 80, n), "phi_o_deg": rng.uniform(0, 360, n)}


@pytest.mark.parametrize("dtype, held", [
    ("datetime64[s]", "datetime64.s."),
    ("m8[s]", "timedelta64.s."),
    ("U5", "text"),
    ("S5", "text"),
    (bool, "booleans .a mask\\?."),
    (complex, "complex numbers .a BRDF is real: keep the real part."),
    ("V8", "raw bytes .|V8."),
    ([("r", "f8"), ("g", "f8")], "records of fields r, g"),
])
def test_an_npz_array_of_no_real_numbers_is_refused_by_what_it_holds(tmp_path, dtype, held):
    """An .npz of dates (datetime64, timedelta64) crashed with h5py's TypeError "No
    conversion path for dtype" (the service answered 500): refused in one line, as
    text, booleans and complex numbers are; a note of dates beside the samples is left
    unread, as a note of text is."""
    path = tmp_path / "d.npz"
    np.savez(path, **_angles(), rgb=np.zeros((200, 3), dtype))
    with pytest.raises(MeasurementsError, match=f"d.npz: array rgb holds {held}, not numbers$"):
        read_measured(path)
    np.savez(path, **_angles(), rgb=np.full((200, 3), 0.3),
             measured_on=np.zeros(200, "datetime64[s]"))
    assert read_measured(path).n == 200


def _half_diff(n: int = 200) -> list[np.ndarray]:
    rng = np.random.default_rng(4)
    theta_h = rng.uniform(0, 40, n)
    return [theta_h, rng.uniform(0, 40, n), rng.uniform(-180, 180, n)]


def _half_diff_csv(path, theta_h, theta_d, phi_d):
    lines = ["theta_h_deg,theta_d_deg,phi_d_deg,r,g,b"]
    lines += [",".join(repr(float(a)) for a in angles) + ",0.2,0.3,0.4"
              for angles in zip(theta_h, theta_d, phi_d, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("column, row, value, said", [
    (0, 5, -40.0, "theta_h_deg is negative in 1 row .first: row 7.: theta_h and theta_d "
                  "run from 0 to 90 degrees"),
    (1, 9, -5.0, "theta_d_deg is negative in 1 row .first: row 11.: theta_h and theta_d "
                 "run from 0 to 90 degrees"),
    (0, 2, 95.0, "theta_h_deg is over 90 degrees in 1 row .first: row 4."),
    (2, 3, 1e6, "phi_d_deg is beyond \\+-720 degrees in 1 row .first: row 5.: an azimuth "
                "is within a turn or two of 0"),
    (2, 3, -800.0, "phi_d_deg is beyond \\+-720 degrees"),
])
def test_half_and_difference_angles_out_of_range_are_refused_by_their_row(
        tmp_path, column, row, value, said):
    """theta_h of -40 degrees and phi_d of 1e6 were fitted (the mapping makes a pair of
    any angles) and called good, where theta_i of -40 or phi_i of 1e6 is refused: the
    same range, named by the file's own column and row (the header is row 1)."""
    angles = _half_diff()
    assert read_measured(_half_diff_csv(tmp_path / "ok.csv", *angles)).n == 200
    angles[column][row] = value
    with pytest.raises(MeasurementsError, match=said):
        read_measured(_half_diff_csv(tmp_path / "bad.csv", *angles))
    names = ("theta_h_deg", "theta_d_deg", "phi_d_deg")
    np.savez(tmp_path / "bad.npz", **dict(zip(names, angles, strict=True)),
             rgb=np.full((200, 3), 0.3))
    with pytest.raises(MeasurementsError, match=said.split(" in 1 row")[0]):
        read_measured(tmp_path / "bad.npz")


@pytest.mark.parametrize("kind", ["vlen", "fixed"])
def test_a_units_attribute_of_bytes_that_are_no_text_is_shown_as_its_bytes(tmp_path, kind):
    """b'\\xff\\xfe' as a units attribute read "unknown angle unit '\\udcff\\udcfe'" (h5py
    gives a variable-length string's bytes that are no UTF-8 as lone surrogates): the
    bytes, as a fixed-length attribute's are shown."""
    import h5py

    angles = _angles()
    with h5py.File(tmp_path / "u.h5", "w") as f:
        for name, a in angles.items():
            f[name.removesuffix("_deg")] = np.radians(a)
        f["rgb"] = np.full((200, 3), 0.3)
        if kind == "vlen":
            f.attrs.create("units", b"\xff\xfe", dtype=h5py.string_dtype("utf-8"))
        else:
            f.attrs["units"] = np.bytes_(b"\xff\xfe")
    with pytest.raises(MeasurementsError) as e:
        read_measured(tmp_path / "u.h5")
    assert str(e.value).endswith("u.h5: attribute units is not UTF-8 text (b'\\xff\\xfe')")
    assert "\\udc" not in str(e.value) and "\n" not in str(e.value)
