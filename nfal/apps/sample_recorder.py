"""Every sample of an identification, kept without a Python object per sample and streamed to its raw CSV.

:class:`SampleRecorder` holds rig time, height, drive frequency, applied and commanded voltage in preallocated columns
(a full collection of the garbage collector then has nothing per sample to walk: docs/hil.md, "Real time that holds")
and writes each sample to the CSV as it arrives.
"""

from __future__ import annotations

import csv
from typing import TextIO

import numpy as np

from nfal.apps.rig_io import RigSample

#: Memory of one sample in the recorder's columns [bytes], and the most the columns may take: they are preallocated
#: for the plan's longest run, and 8 GiB hold about 30 h of samples at 2 kHz.
SAMPLE_BYTES = 5 * 8
MAX_RECORDER_BYTES = 8 << 30
#: The CSV's columns.
CSV_HEADER = ("rig_time_s", "height_m", "drive_frequency_hz", "applied_voltage_v", "commanded_voltage_v", "resting",
              "experiment")


#: The recorder's columns, in :attr:`SampleRecorder.columns`' rows.
TIME, HEIGHT, FREQUENCY, APPLIED, COMMANDED = range(5)


class SampleRecorder:
    """Every sample in preallocated columns (rig time, height, drive frequency, applied and commanded voltage: no
    Python object per sample, so the collector has nothing to walk) and streamed to ``stream`` as CSV (flushed
    every 0.1 s of rig time). ``capacity``: samples held before the columns grow (a copy: give the run's bound,
    :func:`recorder_capacity`). Make it before the first DRIVE: its pages are touched here (numpy asks the kernel for
    huge pages for large arrays, and the first write to each cost 8 ms: 39 ms for the first samples, measured)."""

    def __init__(self, stream: TextIO | None = None, capacity: int = 1 << 14) -> None:
        self.count = 0
        self.columns = _touched((5, max(int(capacity), 16)))
        self._writer = None if stream is None else csv.writer(stream)
        self._stream, self._flushed_at = stream, -np.inf
        if self._writer is not None:
            self._writer.writerow(CSV_HEADER)

    def add(self, samples: list[RigSample], commanded: float, label: str) -> None:
        n, count = self.count, len(samples)
        if n + count > self.columns.shape[1]:
            grown = _touched((5, 2 * (n + count)))
            grown[:, :n] = self.columns[:, :n]
            self.columns = grown
        rows = self.columns[:, n:n + count]
        rows[TIME] = [s.time_s for s in samples]
        rows[HEIGHT] = [s.height_m for s in samples]
        rows[FREQUENCY] = [s.drive_frequency_hz for s in samples]
        rows[APPLIED] = [s.applied_voltage_v for s in samples]
        rows[COMMANDED] = commanded
        self.count = n + count
        if self._writer is None:
            return
        self._writer.writerows((repr(s.time_s), repr(s.height_m), repr(s.drive_frequency_hz), repr(s.applied_voltage_v),
                                repr(commanded), int(s.resting), label) for s in samples)
        if samples and samples[-1].time_s - self._flushed_at > 0.1:
            self._stream.flush()
            self._flushed_at = samples[-1].time_s

    def column(self, index: int, start: int = 0) -> np.ndarray:
        """One column (TIME, HEIGHT, FREQUENCY, APPLIED or COMMANDED) from sample ``start`` on (a view: do not keep it
        across :meth:`add`)."""
        return self.columns[index, start:self.count]

    def arrays(self, start: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(times [s], heights [m]) of the samples from ``start`` on (views: do not keep them across ``add``)."""
        return self.column(TIME, start), self.column(HEIGHT, start)

    def last(self, index: int) -> float:
        """The newest sample's value in a column."""
        return float(self.columns[index, self.count - 1])

    @property
    def duration_s(self) -> float:
        return self.last(TIME) - float(self.columns[TIME, 0]) if self.count else 0.0


def _touched(shape: tuple[int, int]) -> np.ndarray:
    """An array of NaN whose every page has been written (no page fault left for the loop)."""
    return np.full(shape, np.nan)
