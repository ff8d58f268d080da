"""The emulated rig's hardware (nfal.apps.rig_model): the rig structure rig_slow stepped a sample at a time.

:class:`InProcessRig` (the nfal FMUs' slave classes wired by hand) must play exactly what :class:`StructureRig`
(the same structure through the co-simulation master) plays.
"""

from __future__ import annotations

import random

import pytest

from nfal.errors import InvalidParameterError, UnknownConnectorError, UnknownElementError
from nfal.hil.firmware import RigReading
from nfal.apps.rig_model import InProcessRig, StructureRig, open_rig

PERIOD = 5e-4
REST_GAP = 5e-6  # rig_truth.ssv: the object starts resting at the rest gap


def voltages(n: int = 1000, seed: int = 1) -> list[float]:
    """0 V for 50 ticks (resting), then around 60 V (lift-off and a wandering hover)."""
    rng = random.Random(seed)
    return [0.0] * 50 + [60.0 + rng.uniform(-5.0, 5.0) for _ in range(n - 50)]


def play(rig, drive: list[float]) -> list[tuple[RigReading, float]]:
    """(reading, true height) at each tick, the voltage of that tick applied first (as the emulator does)."""
    out = []
    for v in drive:
        rig.apply(v)
        out.append((rig.reading(), rig.true_height))
        rig.advance()
    return out


@pytest.fixture(scope="module")
def rig_slow(fig7_archives):
    return fig7_archives["rig_slow"]


def test_open_rig_plays_rig_slow_in_process_exactly_as_the_master_does(rig_slow):
    drive = voltages()
    with open_rig(rig_slow, PERIOD) as fast, StructureRig(rig_slow, PERIOD) as master:
        assert isinstance(fast, InProcessRig)
        in_process, through_master = play(fast, drive), play(master, drive)
        assert fast.time == pytest.approx(master.time, abs=1e-12) and master.time == pytest.approx(0.5, abs=1e-12)
    assert in_process == through_master  # bit for bit: readings and true heights
    heights = [true for _, true in in_process]
    assert heights[0] == REST_GAP and max(heights) > 20 * REST_GAP  # it did lift off: the comparison means something


def test_both_rigs_report_the_same_excitation_amplitude(rig_slow):
    with open_rig(rig_slow, PERIOD) as fast, StructureRig(rig_slow, PERIOD) as master:
        amplitudes = []
        for v in voltages(300):
            for rig in (fast, master):
                rig.apply(v)
            amplitudes.append((fast.excitation_amplitude, master.excitation_amplitude))
            for rig in (fast, master):
                rig.advance()
    assert all(a == b for a, b in amplitudes) and amplitudes[-1][0] > 1e-6  # equal, and the tracker drove it


def test_at_0_v_the_truth_rests_at_the_rest_gap(rig_slow):
    with open_rig(rig_slow, PERIOD) as rig:
        played = play(rig, [0.0] * 200)
    assert {true for _, true in played} == {REST_GAP}
    assert all(reading.resting for reading, _ in played)


def test_at_100_v_it_lifts_off(rig_slow):
    with open_rig(rig_slow, PERIOD) as rig:
        played = play(rig, [100.0] * 200)
    (first, h0), (last, h_end) = played[0], played[-1]
    assert h0 == REST_GAP and first.resting  # the tick's voltage has not acted yet
    assert not last.resting and h_end > 20 * REST_GAP  # measured: about 260 um after 0.1 s
    assert last.locked and last.drive_frequency > 0


def test_parameters_override_the_structures_values(rig_slow):
    drive = [100.0] * 200
    with open_rig(rig_slow, PERIOD) as default, open_rig(rig_slow, PERIOD, {"Plant.mass": 0.2}) as heavy:
        assert isinstance(heavy, InProcessRig) and heavy.plant.value("mass") == 0.2
        light_h, heavy_h = play(default, drive)[-1][1], play(heavy, drive)[-1][1]
    assert heavy_h < light_h - 10e-6  # heavier (0.2 kg vs 0.1347 kg) is lower; measured: 20 um lower


def test_parameter_overrides_agree_between_the_two_rigs(rig_slow):
    drive, parameters = voltages(300, seed=2), {"Plant.mass": 0.2, "SensorChain.noise_peak": 0.0}
    with open_rig(rig_slow, PERIOD, parameters) as fast, StructureRig(rig_slow, PERIOD, parameters) as master:
        assert play(fast, drive) == play(master, drive)


@pytest.mark.parametrize("parameters, error, match", [
    ({"Nope.mass": 0.2}, UnknownElementError, r"no element 'Nope' \(elements: Plant, ResonanceTracker, SensorChain\)"),
    ({"Plant.nope": 0.2}, UnknownConnectorError, r"'Plant' has no variable 'nope'"),
], ids=["element", "variable"])
@pytest.mark.parametrize("make", [open_rig, StructureRig], ids=["open_rig", "StructureRig"])
def test_an_unknown_name_in_parameters_is_reported(rig_slow, make, parameters, error, match):
    with pytest.raises(error, match=match):
        make(rig_slow, PERIOD, parameters)


@pytest.mark.parametrize("make", [open_rig, StructureRig], ids=["open_rig", "StructureRig"])
def test_close_twice_in_a_with_block_is_safe(rig_slow, make):
    with make(rig_slow, PERIOD) as rig:
        rig.apply(10.0)
        rig.advance()
        rig.close()
    rig.close()


def test_a_closed_loop_is_not_a_rig(fig7_archives):
    """fig7_slow, whose Controller drives the tracker, was played as "the rig": the emulator's drive replaced the
    Controller's link, the loop's Controller and reference ran on each tick (1962 overruns in 2000 ticks)."""
    with pytest.raises(InvalidParameterError, match="here Controller.drive_voltage does: a closed loop, not a rig"):
        open_rig(fig7_archives["fig7_slow"], PERIOD)
