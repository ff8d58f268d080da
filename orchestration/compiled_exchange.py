"""The master's step in C: ``exchange_kernel.c`` makes a step's doSteps and its exchange's get and set calls straight to
the FMUs' functions, where :class:`~nfal.orchestration.master.Master` would make each through ctypes (about 1 µs a
call, and a Python loop around it: a step's floor of 30 µs over five compiled FMUs).

It decides nothing. The master plans the exchange and hands the kernel its transfers (:class:`_Transfer`'s buffers,
value references and columns) and its slaves' doStep functions; the kernel stops at the first call that does not
end cleanly and says which, and the master handles it as it handles a raised call. The values the kernel moves
are the ones the master would move, to the bit (``tests/test_compiled_exchange.py``).

The library is built from source with the system's C compiler (``$CC``, else ``cc``) on first use, once per source
into the user-wide cache. Without a compiler, where ``NFAL_COMPILED_EXCHANGE=off``, or for FMUs exchanging a type a
double does not hold exactly (64-bit integers, an Integer external input), the master runs its own exchange in
Python, as before.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import logging
import os
import platform
import subprocess
from pathlib import Path

from nfal.cache_folder import build_once, cache_root, write_in_one_step

logger = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("exchange_kernel.c")
#: ``off``: every master exchanges in Python (a baseline, and a way to rule the kernel out).
SWITCH = "NFAL_COMPILED_EXCHANGE"
#: The kernel's kinds of transfer (exchange_kernel.c).
GET, LOAD_AND_SET, SET, LOAD = range(4)
#: ctypes value type -> the kernel's code for it: the types whose values a double holds exactly.
TYPE_CODES = {ctypes.c_double: 0, ctypes.c_float: 1, ctypes.c_int8: 2, ctypes.c_uint8: 3, ctypes.c_int16: 4,
              ctypes.c_uint16: 5, ctypes.c_int32: 6, ctypes.c_uint32: 7, ctypes.c_bool: 8}
_FLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off")
_LIBRARIES = ("-lm",)


class _TransferC(ctypes.Structure):
    _fields_ = [("function", ctypes.c_void_p), ("component", ctypes.c_void_p), ("vr", ctypes.c_void_p),
                ("n", ctypes.c_size_t), ("fmi", ctypes.c_int32), ("kind", ctypes.c_int32), ("type", ctypes.c_int32),
                ("buffer", ctypes.c_void_p), ("columns", ctypes.POINTER(ctypes.c_int32)),
                ("scaled", ctypes.POINTER(ctypes.c_uint8)), ("factor", ctypes.POINTER(ctypes.c_double)),
                ("offset", ctypes.POINTER(ctypes.c_double))]


class _SlaveC(ctypes.Structure):
    _fields_ = [("do_step", ctypes.c_void_p), ("component", ctypes.c_void_p), ("fmi", ctypes.c_int32),
                ("seconds", ctypes.c_double), ("last", ctypes.c_double)]


def _build(target: Path) -> None:
    compiler = os.environ.get("CC") or "cc"
    write_in_one_step(target, lambda partial: subprocess.run(
        [compiler, *_FLAGS, "-o", str(partial), str(SOURCE), *_LIBRARIES], check=True, capture_output=True,
        text=True))


@functools.cache
def library() -> ctypes.CDLL | None:
    """The kernel, built on first use (once per source, in the user-wide cache); None where it is switched off or
    cannot be built (said once, at INFO: the master then exchanges in Python)."""
    if os.environ.get(SWITCH, "").lower() == "off":
        return None
    command = " ".join((*_FLAGS, *_LIBRARIES, platform.machine()))
    key = hashlib.sha256(SOURCE.read_bytes() + command.encode()).hexdigest()[:16]
    target = cache_root() / "exchange-kernel" / key / "libnfal_exchange.so"
    try:
        build_once(target.is_file, target.parent / "build.lock", lambda: _build(target))
        kernel = ctypes.CDLL(str(target))
    except (OSError, subprocess.CalledProcessError) as exc:
        reason = getattr(exc, "stderr", None) or exc
        logger.info("the master exchanges in Python: its C kernel could not be built or loaded (%s)", reason)
        return None
    kernel.nfal_transfers.argtypes = [ctypes.POINTER(_TransferC), ctypes.c_int32, ctypes.POINTER(ctypes.c_double),
                                      ctypes.POINTER(ctypes.c_int32)]
    kernel.nfal_do_steps.argtypes = [ctypes.POINTER(_SlaveC), ctypes.c_int32, ctypes.c_int32, ctypes.c_double,
                                     ctypes.c_double, ctypes.POINTER(ctypes.c_int32)]
    kernel.nfal_transfers.restype = kernel.nfal_do_steps.restype = ctypes.c_int
    return kernel


def _address(function) -> int:
    return ctypes.cast(function, ctypes.c_void_p).value


class _Program:
    """Transfers the kernel carries out in one call, in order, each with what it does (``GET``, ``LOAD_AND_SET``,
    ``SET`` or ``LOAD``)."""

    def __init__(self, steps: list[tuple[object, int]]) -> None:
        self.transfers = [transfer for transfer, _ in steps]
        self.table = (_TransferC * max(1, len(steps)))()
        self._keep: list = []  # the arrays the table points into
        for entry, (transfer, kind) in zip(self.table, steps):
            columns = [0] * transfer.n
            scaled, factor, offset = [0] * transfer.n, [1.0] * transfer.n, [0.0] * transfer.n
            for j, column in transfer.pairs:
                columns[j] = column
            for j, column, f, o in transfer.scaled:
                columns[j], scaled[j], factor[j], offset[j] = column, 1, f, o
            arrays = [(ctypes.c_int32 * transfer.n)(*columns), (ctypes.c_uint8 * transfer.n)(*scaled),
                      (ctypes.c_double * transfer.n)(*factor), (ctypes.c_double * transfer.n)(*offset)]
            self._keep.append(arrays)
            entry.function = None if kind == LOAD else _address(transfer.function)
            entry.component = transfer.component
            entry.vr, entry.n = ctypes.addressof(transfer.vr), transfer.n
            entry.fmi, entry.kind, entry.type = transfer.slave.fmi, kind, TYPE_CODES[transfer.buffer._type_]
            entry.buffer = ctypes.addressof(transfer.buffer)
            entry.columns = ctypes.cast(arrays[0], ctypes.POINTER(ctypes.c_int32))
            if transfer.scaled:
                entry.scaled = ctypes.cast(arrays[1], ctypes.POINTER(ctypes.c_uint8))
                entry.factor = ctypes.cast(arrays[2], ctypes.POINTER(ctypes.c_double))
                entry.offset = ctypes.cast(arrays[3], ctypes.POINTER(ctypes.c_double))
        self.count = len(steps)


class CompiledStep:
    """One master's step in the kernel: its slaves' doSteps and its exchange's two programs (before the doSteps and
    after them, :meth:`~nfal.orchestration.exchange.CausalExchange.programs`). Build it with :func:`compiled_step`."""

    def __init__(self, kernel: ctypes.CDLL, slaves: list, before: list, after: list, columns: int,
                 integer_columns: tuple[int, ...]) -> None:
        self._kernel = kernel
        self.slaves = (_SlaveC * len(slaves))()
        for entry, slave in zip(self.slaves, slaves):
            entry.do_step, entry.fmi = _address(slave._do_step), slave.fmi
            entry.component = slave.component
        self.before, self.after = _Program(before), _Program(after)
        self.row = (ctypes.c_double * columns)()
        self.integer_columns = integer_columns  # their values go back to the master's row as ints, as it keeps them
        self._status = ctypes.c_int32()

    def do_steps(self, first: int, t: float, dt: float) -> tuple[int, int, float]:
        """doStep every slave from ``first``: (-1, 0, 0.0), or the index of the first that did not step cleanly,
        its status and (FMI 3.0, terminateSimulation) its last successful time."""
        index = self._kernel.nfal_do_steps(self.slaves, first, len(self.slaves), t, dt, ctypes.byref(self._status))
        return (index, self._status.value, self.slaves[index].last) if index >= 0 else (-1, 0, 0.0)

    def run(self, program: _Program) -> tuple[object | None, int]:
        """Carry out ``program`` on :attr:`row`: (None, 0), or the transfer whose call failed and its status."""
        failed = self._kernel.nfal_transfers(program.table, program.count, self.row, ctypes.byref(self._status))
        return (program.transfers[failed], self._status.value) if failed >= 0 else (None, 0)

    def load_row(self, row: list) -> None:
        """The master's row into :attr:`row` (after the master changed it in Python)."""
        self.row[:] = row

    def store_row(self, row: list) -> None:
        """:attr:`row` into the master's row (in place), Integer and Boolean columns as ints."""
        row[:] = self.row
        for column in self.integer_columns:
            row[column] = int(row[column])

    def seconds(self, index: int) -> float:
        """Wall time in the doSteps of slave ``index`` [s]."""
        return self.slaves[index].seconds


def compiled_step(slaves: list, before: list, after: list, columns: int, integer_columns: tuple[int, ...],
                  integer_inputs: list[str]) -> CompiledStep | None:
    """The kernel's step for these slaves and programs, or None where the master exchanges in Python: the kernel is
    switched off or cannot be built, a transfer moves a type a double does not hold exactly, or an external input is
    an Integer (``integer_inputs``: a Python int may not fit a double; said at DEBUG)."""
    if integer_inputs:
        logger.debug("the master exchanges in Python: Integer external inputs %s", ", ".join(integer_inputs))
        return None
    kernel = library()
    if kernel is None:
        return None
    for transfer, _ in (*before, *after):
        if transfer.buffer._type_ not in TYPE_CODES:
            logger.debug("the master exchanges in Python: %s moves %s values", transfer.name,
                         transfer.buffer._type_.__name__)
            return None
    return CompiledStep(kernel, slaves, before, after, columns, integer_columns)
