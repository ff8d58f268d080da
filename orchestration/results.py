"""Results of a run: a CSV streamed row by row, ``summary.json``, and a PNG of the response.

The CSV's header names every column with its unit (``time [s]``, ``Plant.height [m]``; a column
without a declared unit has no brackets). Rows are written as they come and flushed at least every
``flush_interval_s`` of wall time and when the writer closes, so a run that fails keeps every row
written before the failure. Booleans are written as 0/1.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import itertools
import json
import logging
import math
import os
import re
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from nfal.errors import DataFormatError, InvalidParameterError, ResultsWriteError

logger = logging.getLogger(__name__)

_HEADER = re.compile(r"^(?P<name>.*?)(?: \[(?P<unit>[^\]]*)\])?$", re.DOTALL)  # a name may hold a newline (quoted)


@dataclasses.dataclass(frozen=True)
class Column:
    """A recorded quantity: its name (``Element.variable``), unit and FMI type."""

    name: str
    unit: str | None = None
    type: str = "Real"

    @property
    def header(self) -> str:
        return f"{self.name} [{self.unit}]" if self.unit else self.name


class CsvWriter:
    """Writes result rows to ``path`` as they come (see the module docstring).

    Parameters
    ----------
    path : path-like
    columns : sequence of Column
        The first is the time.
    flush_interval_s : float
        Longest wall time [s] between flushes (0: flush every row).
    """

    def __init__(self, path: str | os.PathLike, columns: Sequence[Column], *, flush_interval_s: float = 0.25) -> None:
        self.path = Path(path)
        self.columns = tuple(columns)
        self.flush_interval_s = float(flush_interval_s)
        self.rows = 0  #: rows written (after a refused write: the rows on disk)
        self._file = file = open(self.path, "w", encoding="utf-8", newline="")  # noqa: SIM115 - closed by close()
        header = io.StringIO()
        csv.writer(header, lineterminator="\n").writerow([c.header for c in self.columns])
        file.write(header.getvalue())
        file.flush()
        self._last_flush = time.monotonic()

    def write(self, row: Sequence[float | int | bool]) -> None:
        """Append one row (as many values as columns); :class:`ResultsWriteError` if the disk refuses it."""
        try:
            self._file.write(",".join(map(repr, row)) + "\n")
            self.rows += 1
            now = time.monotonic()
            if now - self._last_flush >= self.flush_interval_s:
                self._file.flush()
                self._last_flush = now
        except OSError as exc:
            raise self._refused(exc) from None

    def close(self) -> None:
        """Flush and close; :class:`ResultsWriteError` if the last rows cannot be written (the file is closed)."""
        if self._file.closed:
            return
        try:
            self._file.flush()
        except OSError as exc:
            error = exc
        else:
            error = None
        try:
            self._file.close()
        except OSError as exc:
            error = error or exc
        if error is not None:
            raise self._refused(error) from None

    def rows_on_disk(self) -> int:
        """The complete rows in the file now (after a refused write, what was kept)."""
        with open(self.path, "rb") as handle:
            lines = sum(chunk.count(b"\n") for chunk in iter(lambda: handle.read(1 << 20), b""))
        return max(0, lines - 1)

    def _refused(self, exc: OSError) -> ResultsWriteError:
        """The error for a refused write; from then on ``rows`` counts what reached the disk."""
        self.rows = self.rows_on_disk()
        return ResultsWriteError(f"{self.path}: cannot write the results ({exc.strerror or exc}): "
                                 f"{self.rows} rows kept")

    def __enter__(self) -> "CsvWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclasses.dataclass(frozen=True)
class ResultTable:
    """A results CSV read back: ``names``, ``units`` and ``data`` (one row per communication point)."""

    names: tuple[str, ...]
    units: tuple[str | None, ...]
    data: np.ndarray

    @property
    def time(self) -> np.ndarray:
        """The first column [s]."""
        return self.data[:, 0]

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.data[:, self.names.index(name)]
        except ValueError:
            raise KeyError(f"no column {name!r} (columns: {', '.join(self.names)})") from None

    def __contains__(self, name: object) -> bool:
        return name in self.names

    def __len__(self) -> int:
        return self.data.shape[0]

    def unit(self, name: str) -> str | None:
        return self.units[self.names.index(name)]


def read_results(path: str | os.PathLike) -> ResultTable:
    """Read a results CSV written by :class:`CsvWriter` (or any CSV with such a header). The rows are parsed as they are
    read, never held as text: a 10-minute 2 kHz run's 277 MB file needs the table's memory only."""
    path = Path(path)
    try:
        with open(path, encoding="utf-8", newline="") as file:
            header = next(csv.reader(file), None)
            rows = (line for line in file if line.strip())
            first = next(rows, None)
            data = None if first is None else np.loadtxt(itertools.chain([first], rows), delimiter=",", ndmin=2)
    except OSError as exc:
        raise DataFormatError(f"cannot read {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:  # before ValueError, which it is
        raise DataFormatError(f"{path}: not UTF-8 text ({exc.reason}), as a results CSV is written") from None
    except ValueError as exc:
        raise DataFormatError(f"{path}: not a table of numbers: {exc}") from None
    if header is None:
        raise DataFormatError(f"{path}: empty; expected a header line")
    names, units = _header(header)
    if data is None:
        data = np.empty((0, len(names)))
    if data.shape[1] != len(names):
        raise DataFormatError(f"{path}: {data.shape[1]} values per row, {len(names)} names in the header")
    return ResultTable(tuple(names), tuple(units), data)


def _header(header: list[str]) -> tuple[list[str], list[str | None]]:
    """The column names and units of a header row (``name [unit]``)."""
    names, units = [], []
    for cell in header:
        match = _HEADER.match(cell.strip())
        names.append(match["name"])
        units.append(match["unit"])
    return names, units


def _json_ready(value):
    if isinstance(value, Mapping):
        return {str(k): _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.ndarray):
        return _json_ready(value.tolist())
    if isinstance(value, np.generic):
        return _json_ready(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _json_ready(value.to_dict() if hasattr(value, "to_dict") else dataclasses.asdict(value))
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return repr(value)


def write_summary(path: str | os.PathLike, summary: Mapping) -> Path:
    """Write ``summary`` as indented JSON, atomically (a reader never sees half a file).

    numpy values, paths and dataclasses (``to_dict()`` if they have it) are converted; NaN and
    infinities become null.
    """
    path = Path(path)
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(json.dumps(_json_ready(summary), indent=2) + "\n", encoding="utf-8")
    os.replace(temporary, path)
    return path


@dataclasses.dataclass(frozen=True)
class PlotPanel:
    """One panel of the response plot: ``columns`` scaled by ``scale``, with a y-axis label; ``from_start``
    plots each column's change from its first value (a drive frequency of 28.5 kHz that moves by hertz).

    ``PlotPanel(("Controller.reference", "Plant.height"), scale=1e6, ylabel="height [um]")``
    """

    columns: tuple[str, ...]
    scale: float = 1.0
    ylabel: str | None = None
    from_start: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.columns, str):
            object.__setattr__(self, "columns", (self.columns,))
        if not self.columns:
            raise InvalidParameterError("PlotPanel.columns", self.columns, "at least one column name")


_PREFIXES = ((1e-9, "n"), (1e-6, "u"), (1e-3, "m"))


def default_panels(table: ResultTable, *, max_panels: int = 4) -> list[PlotPanel]:
    """Panels for a table nobody described: the non-time columns grouped by unit, in column order,
    small SI quantities shown with a prefix (um rather than 1e-6 m)."""
    groups: dict[str | None, list[str]] = {}
    for name, unit in zip(table.names[1:], table.units[1:]):
        groups.setdefault(unit, []).append(name)
    panels = []
    for unit, names in list(groups.items())[:max_panels]:
        peak = max((float(np.nanmax(np.abs(table[n]))) for n in names if len(table)), default=0.0)
        scale, label = 1.0, unit or ""
        if unit and peak > 0 and unit.isalpha():
            for factor, prefix in _PREFIXES:
                if peak < 1e3 * factor:
                    scale, label = 1.0 / factor, prefix + unit
                    break
        panels.append(PlotPanel(tuple(names), scale, f"[{label}]" if label else None))
    return panels


def plot_response(table: ResultTable, path: str | os.PathLike, panels: Sequence[PlotPanel] | None = None, *,
                  title: str | None = None) -> Path:
    """Plot ``panels`` (default :func:`default_panels`) of ``table`` over time into a PNG at ``path``."""
    path = Path(path)
    response_figure(table, panels, title=title).savefig(path, dpi=120)
    return path


def response_figure(table: ResultTable, panels: Sequence[PlotPanel] | None = None, *, title: str | None = None):
    """The figure of :func:`plot_response`. A ``from_start`` panel whose columns never change (a drive
    frequency nothing moves) is left out, and the title says at which value they stayed."""
    from matplotlib.figure import Figure  # on use (0.3 s); no pyplot: no global state, no display needed

    panels = list(panels) if panels is not None else default_panels(table)
    for panel in panels:
        for name in panel.columns:
            if name not in table:
                raise InvalidParameterError("plot column", name, f"one of {', '.join(table.names[1:])}")
    constant = [p for p in panels if p.from_start and all(_unchanging(table[n]) for n in p.columns)]
    panels = [p for p in panels if p not in constant] or panels[:1]
    notes = [f"{name} constant at {table[name][0]:g}{' ' + table.unit(name) if table.unit(name) else ''}"
             for panel in constant for name in panel.columns if len(table)]
    bucket = -(-len(table) // MAX_LINE_SAMPLES)  # samples a drawn point stands for (1: every sample)
    if bucket > 1:
        notes.append(f"each line drawn through the lowest and highest of every {bucket} samples")
    figure = Figure(figsize=(8, 2.4 * max(1, len(panels)) + 0.6), layout="constrained")
    axes = figure.subplots(max(1, len(panels)), 1, sharex=True, squeeze=False)[:, 0]
    for axis, panel in zip(axes, panels):
        for name in panel.columns:
            values, label = np.asarray(table[name]) * panel.scale, name
            if panel.from_start and len(values):
                values, label = values - values[0], f"{name} - {values[0]:g}"
            if bucket > 1:
                kept = extremes(values, bucket)
                axis.plot(table.time[kept], values[kept], label=label, linewidth=1.0)
            else:
                axis.step(table.time, values, where="post", label=label, linewidth=1.0)
        if panel.ylabel:
            axis.set_ylabel(panel.ylabel)
        axis.grid(True, alpha=0.3)
        # above the panel, never over a line: matplotlib's "best" tried every place against every point drawn (a
        # 7400-sample fig7_slow run drew and saved in 1.2 s with it, 0.8 s without: ``response_figure(table)
        # .savefig(path, dpi=120)`` 8 times each, 2026-11-28)
        axis.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncols=min(2, len(panel.columns)), fontsize="small",
                    frameon=False, borderaxespad=0.2)
    axes[-1].set_xlabel("time [s]")
    if title or notes:
        figure.suptitle("\n".join(filter(None, [title, *notes])))
    return figure


#: Samples a plotted line takes whole; a longer run is drawn through each bucket's extremes (a 10-minute 2 kHz run has
#: 1.2 million samples, which took matplotlib 29 s to draw, for a figure 960 pixels wide).
MAX_LINE_SAMPLES = 20_000


def extremes(values: np.ndarray, bucket: int) -> np.ndarray:
    """The indices of the lowest and highest of every ``bucket`` consecutive ``values`` (and of the first and last),
    in time order: a line through them has the envelope of the line through all, every peak and dip kept, at about
    2 / bucket of the points. A NaN is a bucket's lowest and highest, so it breaks the line as it would."""
    values = np.asarray(values, dtype=float)
    whole = values.size - values.size % bucket
    rows = values[:whole].reshape(-1, bucket)
    offsets = np.arange(0, whole, bucket)
    picked = [offsets + np.argmin(rows, axis=1), offsets + np.argmax(rows, axis=1), [0, values.size - 1]]
    if whole < values.size:
        tail = values[whole:]
        picked.append([whole + np.argmin(tail), whole + np.argmax(tail)])
    return np.unique(np.concatenate(picked))


def _unchanging(values) -> bool:
    """True when ``values`` never move beyond rounding (a change of 1e-9 of their size)."""
    values = np.asarray(values, dtype=float)
    return not values.size or float(np.ptp(values)) <= 1e-9 * float(np.max(np.abs(values)))
