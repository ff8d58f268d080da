"""Reading the small numeric CSV tables users bring: shape scans, equilibrium measurements, reference signals."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from nfal.errors import DataFormatError

#: Largest text file a user brings (a calibration, a shape scan, equilibria): far above any real one (kB).
MAX_TEXT_BYTES = 16 << 20


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
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise DataFormatError(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise DataFormatError(f"{what} {path}: not a UTF-8 text file") from None


def read_numeric_csv(path: str | os.PathLike) -> tuple[list[str], np.ndarray]:
    """Read a CSV of numbers with an optional header line and ``#`` comment lines.

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
    try:  # one record per line: the lines are split already
        records = [[cell.strip() for cell in row] for row in csv.reader(line for _, line in numbered)]
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
            raise DataFormatError(f"{path}: line {number} is not {width} numbers: {','.join(record)!r}")
        rows.append([float(cell) for cell in record])
    if not rows:
        raise DataFormatError(f"{path}: a header but no data rows")
    table = np.array(rows, dtype=float)
    if not np.all(np.isfinite(table)):
        raise DataFormatError(f"{path}: contains NaN or infinite values")
    return names or [f"col{i}" for i in range(width)], table


def _is_numeric(record: list[str]) -> bool:
    try:
        [float(cell) for cell in record]
    except ValueError:
        return False
    return True
