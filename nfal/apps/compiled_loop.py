"""The host's compiled 2 kHz path (``firmware/loop/``), loaded with ctypes: the link and the control law in C, the law
held to :class:`~nfal.models.control_law.DiscreteControlLaw` to the bit (:class:`CompiledLaw`), the loop's structures
(``nfal_loop.h``) as ctypes structures and its rows as a numpy dtype. :mod:`nfal.apps.compiled_run` runs it.

ctypes releases the GIL for the length of every foreign call, so C that runs there waits for no Python thread and no
garbage collection. The library is built from source with the firmware's Makefile (``make loop``: needs ``cc`` and
``make``) on first use.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from nfal.errors import InvalidParameterError
from nfal.hil.plant_channel import build
from nfal.models.control_law import MEASUREMENT_RANGE_M, ControllerState, DiscreteControlLaw

DOUBLES = ctypes.POINTER(ctypes.c_double)


class LawParameters(ctypes.Structure):
    """``nfal_law_params`` (firmware/loop/nfal_law.h)."""

    _fields_ = [(name, ctypes.c_double) for name in (
        "period_s", "filter_rad_s", "max_excitation_m", "tracking_time_s", "reference_low_m", "reference_high_m",
        "measurement_low_m", "measurement_high_m")] + [
        ("has_reference_pair", ctypes.c_int32), ("reference_pair_decay", ctypes.c_double),
        ("has_lift_off", ctypes.c_int32), ("lift_off_decay", ctypes.c_double),
        ("has_lead", ctypes.c_int32), ("lead_held", ctypes.c_double), ("lead_new", ctypes.c_double),
        ("lead_rate", ctypes.c_double), ("has_reference_zero", ctypes.c_int32),
        ("reference_zero_ratio", ctypes.c_double), ("knots", ctypes.c_int32), ("knot", DOUBLES),
        ("pieces", DOUBLES), ("slow_time_s", DOUBLES)] + [(name, ctypes.c_double) for name in (
            "reference_clearance_m", "omega", "fixed_kp", "fixed_ki", "fixed_kd", "fixed_slow_time_s")]


class LawState(ctypes.Structure):
    """``nfal_law_state``: :class:`ControllerState` without the feedforward's members."""

    _fields_ = [(name, ctypes.c_double) for name in (
        "integrator_m", "derivative_m_per_s", "previous_measurement_m", "pair_first_m", "pair_second_m",
        "lead_input_m", "lead_output_m", "reference_lag_m")] + [(name, ctypes.c_int32) for name in (
            "has_previous", "has_pair", "has_lead", "lifting", "has_reference_lag")]

    @classmethod
    def of(cls, state: ControllerState) -> LawState:
        pair, lead = state.reference_pair_m, state.lead_m
        return cls(state.integrator_m, state.derivative_m_per_s, state.previous_measurement_m or 0.0,
                   *(pair or (0.0, 0.0)), *(lead or (0.0, 0.0)), state.reference_lag_m or 0.0,
                   state.previous_measurement_m is not None, pair is not None, lead is not None, state.lifting,
                   state.reference_lag_m is not None)

    def controller_state(self) -> ControllerState:
        return ControllerState(self.integrator_m, self.derivative_m_per_s,
                               self.previous_measurement_m if self.has_previous else None,
                               (self.pair_first_m, self.pair_second_m) if self.has_pair else None,
                               (self.lead_input_m, self.lead_output_m) if self.has_lead else None, bool(self.lifting),
                               self.reference_lag_m if self.has_reference_lag else None)


class Row(ctypes.Structure):
    """``nfal_loop_row``: one row of the Controller's and the HardwareProxy's outputs, and the step's timing."""

    _fields_ = [(name, ctypes.c_double) for name in (
        "reference_m", "command_m", "voltage_v", "height_m", "drive_frequency_hz", "applied_voltage_v", "rig_time_s",
        "measurement_age_s", "lateness_s", "duration_s", "drive_gap_s")] + [(name, ctypes.c_uint32) for name in (
            "status", "fresh", "samples_missed", "frames_dropped", "frames_lost", "rig_faults", "drive_sent")]


#: A ring of rows as numpy sees it.
ROW = np.dtype(Row)


class LinkState(ctypes.Structure):
    """``nfal_loop_link``: the newest measurement and the decoder's memory, handed over and kept by the loop."""

    _fields_ = [(name, ctypes.c_double) for name in (
        "height_m", "drive_frequency_hz", "applied_voltage_v", "rig_time_s", "arrival_s")] + [
        (name, ctypes.c_uint32) for name in ("status", "command_seq", "last_seq", "has_last_seq", "next_drive_seq",
                                             "skip_to_delimiter")] + [
        ("measurements", ctypes.c_uint64)] + [(name, ctypes.c_uint32) for name in (
            "frames_dropped", "frames_lost", "rig_faults")]


class LoopConfig(ctypes.Structure):
    """``nfal_loop_config``."""

    _fields_ = [("fd", ctypes.c_int32), ("rt_priority", ctypes.c_int32), ("steps", ctypes.c_uint64),
                ("period_s", ctypes.c_double), ("spin_s", ctypes.c_double), ("metres_per_volt", ctypes.c_double),
                ("sample_rate_hz", ctypes.c_double), ("max_missed_samples", ctypes.c_uint32),
                ("lockstep", ctypes.c_int32), ("answer_timeout_s", ctypes.c_double),
                ("reference_m", DOUBLES), ("ring", ctypes.POINTER(Row)), ("ring_size", ctypes.c_uint64)]


class Shared(ctypes.Structure):
    """``nfal_loop_shared``: written by the loop and by Python while it runs."""

    _fields_ = [("rows_written", ctypes.c_uint64), ("rows_read", ctypes.c_uint64), ("stop", ctypes.c_int32),
                ("reason", ctypes.c_int32), ("error_number", ctypes.c_int32), ("steps_done", ctypes.c_uint64),
                ("start_s", ctypes.c_double)]


#: ``enum nfal_loop_end``: why the loop ended.
ENDS = ("running", "done", "stopped", "watchdog", "silent", "law input", "port", "restarted", "ring full", "setup",
        "no answer")


@functools.cache
def library() -> ctypes.CDLL:
    """The compiled loop's library, built on first use (FirmwareBuildError names what is missing)."""
    lib = ctypes.CDLL(str(build("loop")))
    lib.nfal_law_step.argtypes = [ctypes.POINTER(LawParameters), ctypes.POINTER(LawState), ctypes.c_double,
                                  ctypes.c_double, DOUBLES]
    lib.nfal_law_step.restype = ctypes.c_int
    lib.nfal_loop_run.argtypes = [ctypes.POINTER(LoopConfig), ctypes.POINTER(LawParameters), ctypes.POINTER(LawState),
                                  ctypes.POINTER(LinkState), ctypes.POINTER(Shared)]
    lib.nfal_loop_run.restype = ctypes.c_int
    lib.nfal_loop_clock.argtypes = []
    lib.nfal_loop_clock.restype = ctypes.c_double
    return lib


class CompiledLaw:
    """A :class:`DiscreteControlLaw` in C: :meth:`step` as the law's, for checks and benches (the loop calls the C
    function itself)."""

    def __init__(self, law: DiscreteControlLaw) -> None:
        constants = law.compiled_constants()
        self._arrays = {name: np.ascontiguousarray(constants.pop(name, ()), dtype=float).ravel()
                        for name in ("knot", "pieces", "slow_time_s")}
        pointers = {name: array.ctypes.data_as(DOUBLES) for name, array in self._arrays.items()}
        self.parameters = LawParameters(**constants, **pointers, knots=len(self._arrays["knot"]))
        self.law = law

    def step(self, state: ControllerState, reference_m: float, measured_m: float) -> tuple[float, ControllerState]:
        """As :meth:`DiscreteControlLaw.step` (its checks raise the same error for an input out of range)."""
        compiled, command = LawState.of(state), ctypes.c_double()
        if library().nfal_law_step(self.parameters, compiled, reference_m, measured_m, ctypes.byref(command)) != 0:
            self.law.step(state, reference_m, measured_m)  # raises, naming the input
            raise InvalidParameterError("measured_m", measured_m, f"within {MEASUREMENT_RANGE_M} m")
        return command.value, compiled.controller_state()
