"""Reference signals (nfal.orchestration.signals): staircases, steps and CSV references."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.properties import examples
from hypothesis import given
from hypothesis import strategies as st

from nfal.models.reference import Staircase
from nfal.orchestration import SignalError, csv_signal, signal_from_spec, staircase, step
from nfal.orchestration.signals import PiecewiseConstant, as_signal, constant, is_step_sequence, steps_of


def test_a_staircase_equals_the_models_class():
    reference = Staircase()
    signal = staircase(reference.levels_m, reference.hold_s, reference.lead_s)
    assert signal.duration_s == pytest.approx(3.7)
    assert signal.values == pytest.approx((60e-6, 100e-6, 140e-6, 180e-6, 140e-6, 100e-6, 60e-6))
    time_s = np.arange(7400) * 5e-4  # the 2 kHz instants of the pure-Python loop
    np.testing.assert_array_equal([signal(t) for t in time_s], reference(time_s))
    converted = as_signal(reference)  # a step sequence of an application, taken as such
    assert isinstance(converted, PiecewiseConstant) and converted.values == signal.values


@pytest.mark.parametrize("levels, hold, lead", [((1.0,), 1.0, 0.1), ((1.0, 2.0), 0.0, 0.1), ((1.0, 2.0), 1.0, -1.0)])
def test_a_bad_staircase_is_refused(levels, hold, lead):
    with pytest.raises(SignalError, match="staircase"):
        staircase(levels, hold, lead)


def test_a_bad_staircase_of_numpy_values_reads_as_plain_numbers():
    with pytest.raises(SignalError, match=r"levels \[0.0001\], hold 0.0 s, lead 0.5 s") as caught:
        staircase(np.array([1e-4]), np.float64(0.0), np.float64(0.5))
    assert "np." not in str(caught.value)


def test_a_communication_point_a_hair_before_a_change_counts_as_at_it():
    signal = staircase((1.0, 2.0), hold_s=1.0, lead_s=0.3)
    assert signal(0.3 - 1e-15) == 2.0 and signal(0.1 * 3) == 2.0 and signal(0.3 - 1e-9) == 1.0


@pytest.mark.parametrize("t, value", [(-1.0, 5.0), (0.0, 5.0), (0.99, 5.0), (1.0, 7.0), (10.0, 7.0)])
def test_step_holds_each_value(t, value):
    assert step(5.0, 7.0, 1.0)(t) == value


def test_csv_with_header_and_comments_is_held_between_rows(tmp_path):
    path = tmp_path / "reference.csv"
    path.write_text("# my reference\ntime_s,reference_m\n0,60e-6\n# a comment\n0.5,1.2e-4\n1.0,8e-5\n")
    signal = csv_signal(path)
    assert [signal(t) for t in (0.0, 0.49, 0.5, 0.99, 1.0, 3.0)] == [60e-6, 60e-6, 1.2e-4, 1.2e-4, 8e-5, 8e-5]
    assert signal.duration_s == 1.0


def test_csv_without_header_and_with_a_named_column(tmp_path):
    (tmp_path / "bare.csv").write_text("0,1\n1,2\n")
    assert csv_signal(tmp_path / "bare.csv")(1.5) == 2.0
    (tmp_path / "wide.csv").write_text("time,a,b\n0,1,10\n1,2,20\n")
    assert csv_signal(tmp_path / "wide.csv", column="b")(1.0) == 20.0
    with pytest.raises(SignalError, match="3 columns"):
        csv_signal(tmp_path / "wide.csv")


@pytest.mark.parametrize("text, message", [
    ("t,r\n0,1\n1,2\n0.5,3\n", "row 3 has t = 0.5 s after t = 1.0 s"),
    ("t,r\n0,1\n0,2\n", "increase strictly"),
    ("t,r\n0,1\nx,2\n", "not 2 numbers"),
    ("t,r\n# measured\n0,1\n\n0.5,abc\n", "line 5 is not 2 numbers"),  # the file's line: comments and blanks count
    ("t,r\n", "no data rows"),
    ("t,r\n0,nan\n", "NaN"),
])
def test_bad_csv_references_are_named(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(SignalError, match=message):
        csv_signal(path)


def test_missing_csv(tmp_path):
    with pytest.raises(SignalError, match="cannot read"):
        csv_signal(tmp_path / "nothing.csv")


@pytest.mark.parametrize("spec, t, value", [
    ("step:0,4,0.5", 0.5, 4.0),
    ("constant:2.5", 9.0, 2.5),
])
def test_specs(spec, t, value):
    assert signal_from_spec(spec)(t) == pytest.approx(value)


@pytest.mark.parametrize("spec", ["staircase", "step:1,2", "sine:1", "missing.csv"])
def test_bad_specs(spec):
    with pytest.raises(SignalError):
        signal_from_spec(spec)


def test_anything_reasonable_becomes_a_signal():
    assert as_signal(3)(1.0) == 3.0
    assert as_signal(Staircase())(0.2) == pytest.approx(100e-6)
    assert as_signal(lambda t: np.float64(2 * t))(1.5) == 3.0 and type(as_signal(lambda t: np.float64(t))(1.0)) is float
    assert as_signal(constant(1.0)) is not None
    with pytest.raises(SignalError):
        as_signal("not a signal")


@examples(100)
@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=1, max_size=20, unique=True),
       st.floats(-2e6, 2e6, allow_nan=False))
def test_zero_order_hold_is_the_value_of_the_last_change_at_or_before_t(times, t):
    times = sorted(times)
    values = list(range(len(times)))
    signal = PiecewiseConstant(times, values)
    earlier = [v for time_, v in zip(times, values) if time_ <= t]
    expected = earlier[-1] if earlier else values[0]
    near = any(abs(t - time_) <= 1e-12 * (1 + abs(t)) for time_ in times)
    assert signal(t) == expected or near


def test_steps_of_a_csv_reference_are_its_levels_and_change_times(tmp_path):
    """Repeated rows are one level; each step is held until the next change, the last until the run's end; the
    result is a step sequence, the staircase's shape."""
    path = tmp_path / "ref.csv"
    path.write_text("time_s,reference_m\n0,60e-6\n0.2,60e-6\n0.5,100e-6\n0.9,100e-6\n1.2,80e-6\n")
    steps, why = steps_of(csv_signal(path), 0.0, 2.0)
    assert why is None and is_step_sequence(steps)
    assert (steps.levels_m, steps.step_times_s, steps.duration_s) == ((60e-6, 100e-6, 80e-6), (0.5, 1.2), 2.0)


@pytest.mark.parametrize("end, expected", [
    (1.0, None),                                           # the level from 0.5 s is held until 1.2 s: cut off
    (1.22, ((60e-6, 100e-6), (0.5,), 1.2)),                # the last level, 20 ms before the end: cut off
    (1.3, ((60e-6, 100e-6, 80e-6), (0.5, 1.2), 1.3)),      # the last level held to the end
])
def test_steps_of_a_run_that_ends_early(end, expected):
    steps, _ = steps_of(PiecewiseConstant([0.0, 0.5, 1.2], [60e-6, 100e-6, 80e-6]), 0.0, end)
    assert (steps and (steps.levels_m, steps.step_times_s, steps.duration_s)) == expected


@pytest.mark.parametrize("signal, reason", [
    (PiecewiseConstant(np.arange(1000) * 1e-3, 60e-6 + 1e-6 * np.sin(np.arange(1000) * 1e-2)),
     "not a sequence of steps"),
    (PiecewiseConstant(np.arange(100) * 1e-2, np.linspace(60e-6, 100e-6, 100)), "not a sequence of steps"),
    (PiecewiseConstant([0.0, 0.3], [60e-6, 60e-6]), "no step"),
    (PiecewiseConstant([0.0, 0.5, 1.5], [60e-6, 100e-6, 80e-6]), "completes its hold by 1 s"),
])
def test_a_reference_without_steps_says_why(signal, reason):
    steps, why = steps_of(signal, 0.0, 1.0)
    assert steps is None and reason in why
