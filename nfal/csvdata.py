"""Reading the small numeric CSV tables users bring: shape scans, equilibrium measurements, reference signals."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from nfal.errors import DataFormatError

#: Largest text file a user brings (a calibration, a shape scan, equilibria): far above any real one (kB).
MAX_TEXT_BYTES = 16 << 20

#: Lines read to tell the delimiter.
DELIMITER_SAMPLE_LINES = 20
#: The delimiters a table may have, tried in this order: a comma, or the semicolon or tab a spreadsheet writes where
#: the decimal mark is a comma.
DELIMITERS = (",", ";", "\t")


def read_user_text(path: str | os.PathLike, what: str) -> str:
    """The text of a small UTF-8 file a user names; :class:`DataFormatError` for anything else (missing, a
    folder, a device such as /dev/zero that never ends, more than :data:`MAX_TEXT_BYTES`, not text)."""
    path = Path(path)
    try:
        if not path.is_file():
            raise DataFormatError(f"cannot read {what} {path}: " + ("not a regular file" if path.exists()
                                                                     else "no such file"))
        size = path.stat().st_size
        if size > MAX_TEXT_BYTES:
            raise DataFormatError(f"{what} {path}: {size / 2**20:,.0f} MiB, more than the {MAX_TEXT_BYTES >> 20} MiB "
                                  "such a file can be")
        return path.read_text(encoding="utf-8-sig")  # a byte-order mark (a spreadsheet's UTF-8 export) is not text
    except OSError as exc:
        raise DataFormatError(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise DataFormatError(f"{what} {path}: not a UTF-8 text file") from None


def read_numeric_csv(path: str | os.PathLike) -> tuple[list[str], np.ndarray]:
    """Read a CSV of numbers with an optional header line and ``#`` comment lines: comma-, or semicolon- or
    tab-separated with a decimal comma (:func:`_delimiter`), as spreadsheets export them.

    Returns
    -------
    names : list of str
        Column names from the header (``col0``, ``col1``, ... when there is none), lower-cased.
    rows : ndarray, shape (n_rows, n_columns)
    """
    path = Path(path)
    text = read_user_text(path, "the table")
    numbered = [(number, line) for number, line in enumerate(text.splitlines(), start=1)
                if line.strip() and not line.lstrip().startswith("#")]
    delimiter = _delimiter([line for _, line in numbered[:DELIMITER_SAMPLE_LINES]])
    try:  # one record per line: the lines are split already
        records = [_cells(row, delimiter) for row in csv.reader((line for _, line in numbered), delimiter=delimiter)]
    except csv.Error as exc:
        raise DataFormatError(f"{path}: not CSV: {exc}") from None
    if not records:
        raise DataFormatError(f"{path}: no data rows")
    names = None
    line_numbers = [number for number, _ in numbered]
    if not _is_numeric(records[0]):
        names, records, line_numbers = [cell.lower() for cell in records[0]], records[1:], line_numbers[1:]
        repeated = sorted({name for name in names if names.count(name) > 1})
        if repeated:
            raise DataFormatError(f"{path}: column(s) {', '.join(repeated)} appear more than once in the header")
    width = len(names) if names else len(records[0])
    rows = []
    for number, record in zip(line_numbers, records):
        if len(record) != width or not _is_numeric(record):
            decimal_comma = " (a decimal comma? between commas, numbers take a point)" if any(
                "," in cell for cell in record) else ""
            raise DataFormatError(f"{path}: line {number} is not {width} number{'s' if width > 1 else ''}: "
                                  f"{delimiter.join(record)!r}{decimal_comma}")
        rows.append([float(cell) for cell in record])
    if not rows:
        raise DataFormatError(f"{path}: a header but no data rows")
    table = np.array(rows, dtype=float)
    if not np.all(np.isfinite(table)):
        raise DataFormatError(f"{path}: contains NaN or infinite values")
    return names or [f"col{i}" for i in range(width)], table


def _delimiter(lines: list[str]) -> str:
    """The first of :data:`DELIMITERS` that splits ``lines`` (after a header) into rows of numbers of one width; a
    comma if none does (the rows' errors are then named by line). A semicolon or a tab is never part of a number,
    where a comma can be the decimal mark: '0,5;1,2' is two numbers, not three cells."""
    for delimiter in DELIMITERS:
        if delimiter != "," and not any(delimiter in line for line in lines):  # a ragged comma table stays one
            continue
        try:
            records = [_cells(row, delimiter) for row in csv.reader(lines, delimiter=delimiter)]
        except csv.Error:
            continue
        data = records[1:] if records and not _is_numeric(records[0]) else records
        if data and all(record and len(record) == len(data[0]) and _is_numeric(record) for record in data):
            return delimiter
    return ","


def _cells(row: list[str], delimiter: str) -> list[str]:
    """A record's cells, stripped, without the empty ones a spreadsheet leaves after the last column; between
    semicolons or tabs, a comma in a number is the decimal mark (6,0e-5 is 6.0e-5; a header's names keep theirs)."""
    cells = [cell.strip() for cell in row]
    if delimiter != ",":
        cells = [_decimal_point(cell) for cell in cells]
    while cells and not cells[-1]:
        cells.pop()
    return cells


def _decimal_point(cell: str) -> str:
    pointed = cell.replace(",", ".")
    return pointed if _is_numeric([pointed]) else cell


def _is_numeric(record: list[str]) -> bool:
    try:
        [float(cell) for cell in record]
    except ValueError:
        return False
    return True
