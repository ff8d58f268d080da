"""How errors read (nfal/errors.py, the master's FmuCallError): the cause first, values as a user wrote them."""

from __future__ import annotations

import collections
import types

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

from nfal.errors import FmuCallError, InvalidParameterError, SlaveCallError, shown, span_um
from nfal.orchestration.master import Master


@pytest.mark.parametrize("value, text", [
    (np.float64(150.0), "150.0"),
    (np.int64(3), "3"),
    (np.array(2.5), "2.5"),
    (np.array([5e-05, 1e-04]), "[5e-05, 0.0001]"),
    ((np.float64(1.0), 2), "(1.0, 2)"),
    (np.linspace(1.0, 31.0, 31), "[1.0, 2.0, ..., 31.0] (31 values)"),
    ("piston", "'piston'"),
    (True, "True"),
])
def test_values_are_shown_without_numpy_reprs(value, text):
    assert shown(value) == text


def test_a_long_value_stays_one_short_line():
    text = str(InvalidParameterError("heights", np.geomspace(1e-6, 1e-3, 1000).reshape(10, 100), "clearances"))
    assert "\n" not in text and "array" not in text and len(text) < 300


def test_a_value_can_be_shown_as_a_range():
    error = InvalidParameterError("heights", np.array([50e-6, 200e-6]), "within 80.0–98.0 µm",
                                  as_shown=span_um(50e-6, 200e-6))
    assert str(error) == "heights = 50.0–200.0 µm is invalid: must be within 80.0–98.0 µm"
    assert str(error.within("damping")).startswith("damping.heights = 50.0–200.0 µm is invalid")


def test_our_fmus_reason_comes_first_and_the_fmi_call_after_it():
    reason = str(SlaveCallError("Controller", "the set-up from the parameters", "mass = -1.0 is invalid: must be > 0"))
    assert reason == "Controller: mass = -1.0 is invalid: must be > 0 (in the set-up from the parameters)"
    error = FmuCallError("Controller", "fmi2GetReal", 3, 0.0, [reason], "for saturated_time")
    assert str(error) == ("Controller: mass = -1.0 is invalid: must be > 0 (in the set-up from the parameters; "
                          "fmi2GetReal for saturated_time at t = 0 s)")


@pytest.mark.parametrize("status, time, messages, text", [
    (3, 0.5, ["toy plant fails by design"], "Plant: toy plant fails by design (in fmi2DoStep at t = 0.5 s)"),
    (4, 0.5, [], "Plant: the FMU logged no reason (in fmi2DoStep at t = 0.5 s, which returned fatal)"),
    (3, float("nan"), ["no licence"], "Plant: no licence (in fmi2DoStep)"),
])
def test_anyones_fmu_reason_comes_first(status, time, messages, text):
    assert str(FmuCallError("Plant", "fmi2DoStep", status, time, messages)) == text


def test_the_master_puts_the_error_before_earlier_warnings():
    earlier, cause = "Controller: drive saturated for 0.1 s", "Controller: x bad"
    slave = types.SimpleNamespace(name="Controller", state="running", messages=collections.deque([earlier, cause]),
                                  reasons=collections.deque([cause]))
    error = Master._failure(types.SimpleNamespace(time=0.25), slave, FMICallException("fmi2DoStep", 3))
    assert str(error).startswith("Controller: x bad; drive saturated for 0.1 s (in fmi2DoStep at t = 0.25 s)")
    assert slave.state == "error"
