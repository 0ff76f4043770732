"""An Excel workbook's sheet of samples (``.xlsx``, ``.xlsm``), read as the CSV it
would be saved as: its first row of cells the header, one row per sample (or per
sample and channel: :mod:`brdffit.io.long_layout`), as :mod:`brdffit.io.text_samples`
reads a CSV's.

openpyxl reads the workbook (read-only, the cells' values: a formula's last computed
value, as Excel shows it). A number keeps every digit Excel stored; a number Excel
holds as text (``0,25``, typed in a comma-decimal locale) is text here too, and read as
a CSV's decimal comma is. Which sheet: the first that reads as samples, in the
workbook's order, visible sheets before hidden ones (a lab's workbook often opens on
a sheet of notes); the result names it, of how many, whether it is hidden, and why
each sheet before it was passed over (``input.sheet``, ``input.sheets``,
``input.sheet_hidden``, ``input.sheets_passed``). A workbook is a zip archive of XML:
its members' declared sizes are weighed before it is opened, so that a few MB cannot
expand to GBs.
"""

from __future__ import annotations

import datetime
import re
import zipfile
from collections.abc import Iterator
from pathlib import Path

from brdffit.io import variables
from brdffit.io.measurements import MAX_SAMPLES, MeasurementsError

#: The part every .xlsx holds (an .npz, a .docx or an .ods is another zip archive).
WORKBOOK_PART = "xl/workbook.xml"
#: The most bytes a workbook's parts may expand to: a sheet of two million rows of
#: seven numbers is ~400 MB of XML.
MAX_EXPANDED = 1 << 30
#: The most columns a sheet's rows may reach: as many as a CSV's header may name
#: (``brdffit.io.text_samples.MAX_COLUMNS``: a spectral list of one column per nm).
MAX_COLUMNS = 10_000
#: The most cells a sheet's rows may span, each row as wide as its last cell (or as
#: the range the sheet declares): about as many as :data:`MAX_EXPANDED` of XML can
#: hold (20 bytes or more a cell). openpyxl gives every row as wide as the sheet, so an
#: empty cell costs no byte of XML and is read all the same: a 5 KB sheet with one
#: cell at XFD5000 was 82 million cells, 11 s (~0.13 us each), and one at XFD1048576
#: ran for hours.
MAX_CELLS = 50_000_000


def is_xlsx(path: str | Path) -> bool:
    """Whether ``path`` is a zip archive holding an Excel workbook's parts."""
    try:
        with zipfile.ZipFile(path) as z:
            return WORKBOOK_PART in z.namelist()
    except (OSError, zipfile.BadZipFile, ValueError):
        return False


def sheet_texts(path: str | Path, source: str,
                sheet: str | None = None) -> Iterator[tuple[str, str, int, bool]]:
    """Each sheet with a cell, in the workbook's order, the visible ones first (a
    hidden sheet before the one on show was fitted instead of it), as tab-separated
    text a CSV reader reads, a line per row (:func:`_lines`; a cell's tabs and line
    breaks made blanks, its quotes quoted as a CSV's): ``(name, text, how many sheets
    the workbook has, whether it is hidden)``. A sheet is read when it is asked for:
    the reader stops at the first that holds samples. With ``sheet``, that sheet alone
    (MeasurementsError naming the workbook's sheets where it has none of that name, or
    where it is empty)."""
    import openpyxl

    _weighed(path, source)
    # from an open file, not a path: openpyxl refuses a path not named .xlsx (an upload's
    # temporary copy, a workbook named .csv)
    with open(path, "rb") as raw:
        book = None
        try:
            book = openpyxl.load_workbook(raw, read_only=True, data_only=True)
            names = book.sheetnames
            if sheet is not None and sheet not in names:
                raise MeasurementsError(source, f"no sheet named {sheet!r}: the workbook's "
                                                "sheets are " + ", ".join(map(repr, names)))
            hidden = {n for n in names if getattr(book[n], "sheet_state", "visible")
                      != "visible"}
            order = ([n for n in names if n not in hidden] + [n for n in names if n in hidden]
                     if sheet is None else [sheet])
            parts = _sheet_parts(path)
            for name in order:
                merges = _merged_header_ranges(path, parts.get(name))
                if lines := _lines(book[name], source, merges):
                    yield name, "\n".join(lines) + "\n", len(names), name in hidden
                elif sheet is not None:
                    raise MeasurementsError(source, f"sheet {sheet!r} holds no cells")
        except MeasurementsError:
            raise
        except Exception as e:  # noqa: BLE001 - openpyxl raises many kinds on a damaged
            # file (opening it, or reading a sheet's XML as it streams)
            raise MeasurementsError(source, "not a readable Excel workbook "
                                            f"({variables.said(e)})") from None
        finally:
            if book is not None:
                book.close()


def uncomputed_formula(path: str | Path, sheet: str) -> str | None:
    """The first cell of ``sheet`` that holds a formula and no value (a workbook saved
    by a program that computes none: its value reads as empty), as ``E2 (=E1*2)``; None
    where there is none. For the refusal of its row: it read "has 6 values", of a row
    of 7 formulas and numbers."""
    import openpyxl

    with open(path, "rb") as raw, open(path, "rb") as raw_again:
        values = openpyxl.load_workbook(raw, read_only=True, data_only=True)
        formulas = openpyxl.load_workbook(raw_again, read_only=True, data_only=False)
        for book in (values, formulas):  # the cells _lines read, not the declared range
            book[sheet].reset_dimensions()
        try:
            for row_values, row_formulas in zip(values[sheet].iter_rows(),
                                                formulas[sheet].iter_rows(), strict=False):
                for value, formula in zip(row_values, row_formulas, strict=False):
                    if (value.value is None and isinstance(formula.value, str)
                            and formula.value.startswith("=")):
                        return f"{formula.coordinate} ({formula.value[:40]})"
        finally:
            values.close()
            formulas.close()
    return None


def _weighed(path: str | Path, source: str) -> None:
    try:
        with zipfile.ZipFile(path) as z:
            expanded = sum(member.file_size for member in z.infolist())
    except (OSError, zipfile.BadZipFile, ValueError) as e:
        raise MeasurementsError(source, "not a readable Excel workbook "
                                        f"({variables.said(e)})") from None
    if expanded > MAX_EXPANDED:
        raise MeasurementsError(source, f"an Excel workbook whose parts expand to "
                                        f"{expanded:,} bytes: more than a sample list's "
                                        f"({MAX_EXPANDED:,}); save the sheet as CSV")


def _lines(sheet, source: str, merges: list[tuple[int, int, int, int]] = ()) -> list[str]:
    """The sheet's rows as tab-separated lines, one per row (so that a line's number is
    its row's: the reader's "row 5" is the sheet's row 5; an empty row an empty line);
    none where the sheet holds no cell. ``merges``: the merged cells of its first rows
    (:func:`_merged_header_ranges`), read as :func:`_unmerged` says."""
    _sized(sheet, source)
    rows: list[list[str]] = []
    spanned = 0
    for k, row in enumerate(sheet.iter_rows(values_only=True), start=1):
        if k > MAX_SAMPLES + 1000:  # the header, units and comment rows, with room
            raise MeasurementsError(source, f"an Excel sheet of more than {k - 1:,} rows: "
                                            "more than a sample list read here "
                                            f"({MAX_SAMPLES:,})")
        spanned += len(row)
        if len(row) > MAX_COLUMNS or spanned > MAX_CELLS:
            raise MeasurementsError(source, _too_wide(
                sheet.title, f"row {k} reaches column {_letters(len(row))} ({len(row):,} "
                             "columns)" if len(row) > MAX_COLUMNS
                else f"rows 1 to {k:,} span {spanned:,} cells", len(row)))
        cells = [_cell(v) for v in row]
        while cells and not cells[-1].strip():
            cells.pop()
        rows.append(cells)
        if k == HEADER_ROWS and merges:
            _unmerged(rows, merges)
    if len(rows) < HEADER_ROWS and merges:
        _unmerged(rows, merges)
    lines = ["\t".join(cells) for cells in rows]
    while lines and not lines[-1]:
        lines.pop()
    return lines


def _sized(sheet, source: str) -> None:
    """Refuses a sheet whose declared range (its XML's dimension record) spans more than
    a sample list's columns or cells, before a row is read; then forgets that range, so
    that each row is read as wide as its own cells reach (a sheet that declares none,
    or one too small, is weighed row by row in :func:`_lines`; one too small cut its
    rows short, unsaid)."""
    rows, columns = sheet.max_row, sheet.max_column
    if rows and columns and (columns > MAX_COLUMNS or rows * columns > MAX_CELLS):
        raise MeasurementsError(source, _too_wide(
            sheet.title, f"declares cells up to {_letters(columns)}{rows} "
                         f"({rows:,} rows of {columns:,} columns)", columns))
    sheet.reset_dimensions()


def _too_wide(title: str, found: str, columns: int) -> str:
    """Why a sheet is refused for its width (``columns`` over :data:`MAX_COLUMNS`) or
    its cells: what was ``found``, and the limit (a sample list has its angles and
    values, one per channel or wavelength)."""
    limit = (f"{MAX_COLUMNS:,} columns" if columns > MAX_COLUMNS else f"{MAX_CELLS:,} cells")
    return (f"sheet {title!r} {found}: more than a sample list's ({limit}); clear the cells "
            "beyond its samples (a stray value far right or down), or save it as CSV")


#: The rows at the top of a sheet whose merged cells are read as a header's
#: (:func:`_unmerged`); merged cells below them are left as they are.
HEADER_ROWS = 20


def _unmerged(rows: list[list[str]], merges) -> None:
    """The header of a sheet whose first rows hold merged cells, as one row a CSV
    reader reads (openpyxl's read-only sheets give a merged range's value in its first
    cell alone, and the rest empty). In place, keeping each row's number; only ranges
    above the first row that holds a number are read so:

    - a row whose only content is one range across every named column is a title
      (``Gonioreflectometer run 12``): made a comment (``# ...``);
    - a range across columns over a row of names (``incident (deg)`` over ``theta``
      and ``phi``; ``BRDF`` over ``R``, ``G``, ``B``) names each of its columns, and a
      range down rows (``theta_i`` over two rows) its column in each: the rows of
      such a header are read as one, its last, each column's names joined in order
      (``incident (deg) theta``, ``BRDF R``: ``brdffit.io.columns`` reads both), and
      the rows above it are made comments. A row below it (a row of units) stays.

    A range that reaches a row of numbers (a sample's name merged down its rows) is
    left as it is, as is one with nothing under it to name."""
    def numeric(cells: list[str]) -> bool:
        return any(_a_number(c) for c in cells)

    def named(cells: list[str]) -> list[int]:
        return [c for c, v in enumerate(cells) if v.strip()]

    data = next((r for r, cells in enumerate(rows) if numeric(cells)), len(rows))
    above = [r for r in range(data) if named(rows[r])]
    if not above:
        return
    names = named(rows[above[-1]])  # the last row of names above the numbers
    groups, block = [], set()
    for r1, c1, r2, c2 in merges:
        if r2 >= data or c1 >= len(rows[r1]) or not rows[r1][c1].strip():
            continue  # among the numbers, or empty
        if (r1 == r2 and r1 < above[-1] and named(rows[r1]) == [c1]
                and c1 <= names[0] and c2 >= names[-1]):
            rows[r1] = [f"# {rows[r1][c1]}"]  # a title over every column
            continue
        bottom = r2 if r2 > r1 else r1 + 1  # down: its own rows; across: the names under it
        if bottom >= data:
            continue  # nothing under it to name
        groups.append((r1, c1, r2, c2))
        block.update(range(r1, bottom + 1))
    if not block:
        return
    first = last = min(block)
    while last + 1 in block:  # one run of header rows (another, lower, is left alone)
        last += 1
    for r1, c1, r2, c2 in groups:
        if not first <= r1 <= last:
            continue
        value = rows[r1][c1]
        for r in range(r1, r2 + 1):
            rows[r].extend([""] * (c2 + 1 - len(rows[r])))
            for c in range(c1, c2 + 1):
                if not rows[r][c].strip():
                    rows[r][c] = value
    width = max(len(rows[r]) for r in range(first, last + 1))
    joined = []
    for c in range(width):
        column: list[str] = []
        for r in range(first, last + 1):
            cell = rows[r][c].strip() if c < len(rows[r]) else ""
            if cell and cell not in column:
                column.append(cell)
        joined.append(" ".join(column))
    for r in range(first, last):
        rows[r] = [f"# {' '.join(c for c in rows[r] if c.strip())}"]
    rows[last] = joined


def _a_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _sheet_parts(path: str | Path) -> dict[str, str]:
    """Each sheet's name -> its XML part in the archive (through workbook.xml and its
    relationships); empty where they cannot be read (its sheets are then read without
    their merged cells)."""
    import xml.etree.ElementTree as ET

    rel = "{http://schemas.openxmlformats.org/officeDocument/2006/relationships}id"
    try:
        with zipfile.ZipFile(path) as z:
            book = ET.fromstring(z.read(WORKBOOK_PART))
            rels = ET.fromstring(z.read("xl/_rels/workbook.xml.rels"))
    except (OSError, KeyError, zipfile.BadZipFile, ET.ParseError, ValueError):
        return {}
    targets = {e.get("Id"): e.get("Target") for e in rels.iter() if e.get("Target")}
    parts = {}
    for e in book.iter():
        if e.tag.endswith("}sheet") and (target := targets.get(e.get(rel))) is not None:
            parts[e.get("name")] = (target.lstrip("/") if target.startswith("/")
                                    else f"xl/{target}")
    return parts


def _merged_header_ranges(path: str | Path, part: str | None) -> list[tuple[int, int, int, int]]:
    """The merged ranges of the sheet whose XML is ``part`` (:func:`_sheet_parts`) that
    begin in its first :data:`HEADER_ROWS` rows, as 0-based (first row, first column,
    last row, last column): read from its ``mergeCells``, after its rows, which
    openpyxl's read-only mode does not read. None found, or a part that cannot be read,
    is an empty list: the sheet is then read as it was."""
    if part is None:
        return []
    try:
        with zipfile.ZipFile(path) as z:
            return _merge_refs(z, part)
    except (OSError, KeyError, zipfile.BadZipFile, ValueError):
        return []


_MERGE = re.compile(rb"<(?:\w+:)?mergeCell\b[^>]*?\bref=\"([A-Z]+)(\d+):([A-Z]+)(\d+)\"")


def _merge_refs(z: zipfile.ZipFile, part: str) -> list[tuple[int, int, int, int]]:
    # streamed: a sheet's XML may be hundreds of MB, and its merged cells come last
    found, tail = [], b""
    with z.open(part) as xml:
        while chunk := xml.read(1 << 20):
            text = tail + chunk
            for m in _MERGE.finditer(text):
                r1, r2 = int(m[2]) - 1, int(m[4]) - 1
                if r1 < HEADER_ROWS:
                    found.append((r1, _column(m[1]), r2, _column(m[3])))
            tail = text[-200:]  # a range cut in two by the chunk: found whole next time
    return sorted(set(found))


def _column(letters: bytes) -> int:
    n = 0
    for ch in letters:
        n = n * 26 + ch - 64
    return n - 1


def _letters(column: int) -> str:
    """Excel's letters of the 1-based ``column`` (16384: ``XFD``; :func:`_column`
    reads them back, 0-based)."""
    letters = ""
    while column > 0:
        column, k = divmod(column - 1, 26)
        letters = chr(65 + k) + letters
    return letters


def _cell(value) -> str:
    """A cell as a CSV would hold it: a number with every digit, a date in ISO form,
    text with its tabs and line breaks made blanks (they would split the row)."""
    if value is None:
        return ""
    if isinstance(value, bool):  # before int: True is an int
        return str(value).upper()
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, datetime.datetime | datetime.date | datetime.time):
        return value.isoformat()
    text = str(value)
    if any(c in text for c in "\t\r\n"):
        text = " ".join(text.split())
    return f'"{text.replace(chr(34), chr(34) * 2)}"' if '"' in text else text  # CSV quoting
