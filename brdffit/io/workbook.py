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
            for name in order:
                if lines := _lines(book[name], source):
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


def _lines(sheet, source: str) -> list[str]:
    """The sheet's rows as tab-separated lines, one per row (so that a line's number is
    its row's: the reader's "row 5" is the sheet's row 5; an empty row an empty line);
    none where the sheet holds no cell."""
    lines: list[str] = []
    for k, row in enumerate(sheet.iter_rows(values_only=True), start=1):
        if k > MAX_SAMPLES + 1000:  # the header, units and comment rows, with room
            raise MeasurementsError(source, f"an Excel sheet of more than {k - 1:,} rows: "
                                            "more than a sample list read here "
                                            f"({MAX_SAMPLES:,})")
        cells = [_cell(v) for v in row]
        while cells and not cells[-1].strip():
            cells.pop()
        lines.append("\t".join(cells))
    while lines and not lines[-1]:
        lines.pop()
    return lines


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
