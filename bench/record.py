"""The shape every bench shares: what it measured, written to ``bench/results/<name>.json``, and its tables.

A bench is a script ``bench/<script>.py`` run from the repository root (``python bench/<script>.py --help``). It
measures, then calls :func:`save` with its raw measurements (``data``): the file also records the machine, the
command, the date and the load average. The script's ``tables(result)`` turns a result into :class:`Table` s (the
baseline of a ratio is measured in the same run, so it is in ``data`` too), and ``findings(result)`` into sentences
whose numbers come from ``data``; a bench that reports free-form lines (:func:`report`) saves them as ``lines``,
which the document lists (no ``tables`` needed). ``python bench/report.py`` writes docs/benchmarks.md from every
result file with those functions: no number there is copied by hand.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path

from machine import describe

RESULTS = Path(__file__).resolve().parent / "results"


@dataclasses.dataclass
class Table:
    """A markdown table: a title line, the column names and the rows (already formatted)."""

    title: str
    columns: list[str]
    rows: list[list[str]]

    def markdown(self) -> str:
        lines = [self.title, ""] if self.title else []
        lines += ["| " + " | ".join(self.columns) + " |", "|" + "---|" * len(self.columns)]
        lines += ["| " + " | ".join(str(cell).replace("|", "\\|") for cell in row) + " |" for row in self.rows]
        return "\n".join(lines)


def cells(line: str) -> list[str]:
    """The cells of a markdown table row that a bench printed as it went (``| a | b |`` -> ``["a", "b"]``)."""
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def save(name: str, data: dict, *, argv: list[str] | None = None) -> Path:
    """Write ``bench/results/<name>.json``: the bench's ``data`` with the machine, command, date and load; its path.
    Call it after every run of a long bench, so that a bench stopped half-way keeps what it measured."""
    script = Path(sys.argv[0]).name
    argv = sys.argv[1:] if argv is None else argv
    result = {"bench": name, "script": script, "machine": describe(),
              "command": " ".join(["python", f"bench/{script}", *argv]),
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
              "load_average": [round(load, 2) for load in os.getloadavg()], **data}
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    return path


#: What a bench that reports line by line has said (:func:`report`): its result file's ``lines``.
LINES: list[str] = []


def report(line: str) -> None:
    """Print ``line`` and keep it for the result file (a bench of free-form lines, as the host checks are)."""
    print(line, flush=True)
    LINES.append(line)


def show(tables: list[Table], findings: list[str] = ()) -> None:
    """Print a bench's tables and findings as they appear in docs/benchmarks.md."""
    for table in tables:
        print("\n" + table.markdown())
    for finding in findings:
        print(f"* {finding}")
