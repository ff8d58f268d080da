"""The compiled 2 kHz path (firmware/loop/): its law equals DiscreteControlLaw to the bit, and in lockstep its run
equals the master's run of the FMUs to the bit; on the rig's clock, through the CLI, and stopped by a signal."""

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from helpers.rig import run_hil
from helpers.warm_nfal import popen

from nfal.apps.compiled_loop import CompiledLaw
from nfal.apps.compiled_run import run_compiled
from nfal.cli import main
from nfal.errors import InvalidParameterError, SimulationError, UnsupportedFeatureError
from nfal.fmus.controller import Controller
from nfal.models.reference import Staircase
from nfal.models.control_law import LIFT_OFF_TIME_S, DiscreteControlLaw
from nfal.models.calibration import paper_calibration
from nfal.models.pid_design import DesignSpec, design_schedule, fixed_design
from nfal.models.plant import SimplifiedPlant
from nfal.models.rig import RigParameters
from nfal.models.table2 import REFERENCE_ZERO_RATIO
from nfal.models.transducer import Transducer
from nfal.orchestration import read_ssp
from nfal.orchestration.resolve import resolve
from nfal.orchestration.results import read_results

SAMPLED = design_schedule(None, spec=DesignSpec(sample_rate_hz=2000.0, reference_zero=REFERENCE_ZERO_RATIO))
LAWS = {
    "the paper's law": DiscreteControlLaw(design_schedule()),
    "the Controller FMU's": DiscreteControlLaw(SAMPLED, lift_off_time_s=LIFT_OFF_TIME_S,
                                               actuator_lag_s=Transducer().time_constant_s(),
                                               reference_zero_ratio=REFERENCE_ZERO_RATIO),
    "reference pair, tracking time": DiscreteControlLaw(SAMPLED, reference_filter_s=0.01, tracking_time_s=2e-3,
                                                        lift_off_time_s=0.04, max_excitation_m=6e-6),
    "linear at 80 um": DiscreteControlLaw(fixed_design(80e-6), reference_zero_ratio=1.0, actuator_lag_s=5e-3),
}


def _trajectory(seed: int, n: int = 4000):
    """References on a staircase, measurements a random walk from rest (5 um) with jumps, across the whole
    schedule and beyond it."""
    rng = np.random.default_rng(seed)
    references = np.repeat(rng.uniform(50e-6, 200e-6, n // 400 + 1), 400)[:n]
    measured = np.clip(5e-6 + np.cumsum(rng.normal(0.0, 2e-6, n)) + rng.choice([0.0, 40e-6], n, p=[0.99, 0.01]),
                       0.0, 1e-3)
    return references, measured


@pytest.mark.parametrize("name", LAWS)
def test_the_compiled_law_is_the_python_law_to_the_bit(name):
    law = LAWS[name]
    compiled = CompiledLaw(law)
    for seed in range(3):
        python = c = law.initial_state(120e-6, 3e-6)
        for reference, measured in zip(*_trajectory(seed)):
            expected, python = law.step(python, reference, measured)
            command, c = compiled.step(c, reference, measured)
            assert (command, c) == (expected, python)


def test_it_lifts_off_saturates_and_leads_on_the_way():
    """The trajectories reach what the law can do: lift-off, saturation, the lead's clamp (else the test is weak)."""
    law = LAWS["the Controller FMU's"]
    compiled, state, seen = CompiledLaw(law), law.initial_state(120e-6, 3e-6), set()
    for reference, measured in zip(*_trajectory(0)):
        command, state = compiled.step(state, reference, measured)
        seen |= {"lifting"} if state.lifting else set()
        seen |= {"saturated"} if command == law.max_excitation_m else set()
        seen |= {"off"} if command == 0.0 else set()
    assert seen == {"lifting", "saturated", "off"}


def test_an_input_out_of_range_raises_as_the_python_law_does():
    law = LAWS["the paper's law"]
    compiled, state = CompiledLaw(law), law.initial_state(120e-6, 3e-6)
    for reference, measured in ((300e-6, 100e-6), (100e-6, -1e-6), (100e-6, float("nan")), (float("inf"), 1e-4)):
        with pytest.raises(InvalidParameterError):
            compiled.step(state, reference, measured)


def test_a_law_with_a_feedforward_path_is_refused_by_name():
    plant = SimplifiedPlant(RigParameters(), paper_calibration())
    law = DiscreteControlLaw(SAMPLED, reference_filter_s=0.01, feedforward=plant)
    with pytest.raises(InvalidParameterError, match="feedforward"):
        CompiledLaw(law)


# --- the loop against the emulator -------------------------------------------------------------------------------
#: Columns of the wall clock, not of the loop: they differ between any two runs.
WALL_CLOCK = ("proxy.measurement_age", "proxy.drive_gap_max", "proxy.drive_gap_p50",
              "proxy.drive_gap_p99")
#: The link's counts, which include what a loaded machine lost of the rig's stream before the first DRIVE (the port
#: full while the host set up; taken in before row 0 by the compiled loop, with the first DRIVE by the proxy).
SET_UP_BACKLOG = ("proxy.frames_dropped", "proxy.frames_lost")
#: From rest through lift-off and a step.
LIFT_AND_STEP = Staircase((100e-6, 140e-6), hold_s=0.3, lead_s=0.4)
STEPS = round(LIFT_AND_STEP.duration_s * 2000)


def _compiled(fig7_archives, port: str, out, reference=LIFT_AND_STEP, **parameters):
    return run_compiled(fig7_archives["fig7_hil"], reference=reference, stop_time=reference.duration_s,
                        parameters={"proxy.port": port, **parameters}, out_dir=out, plot=False)


@pytest.mark.slow
def test_in_lockstep_the_compiled_loop_is_the_fmu_loop_to_the_bit(fig7_archives, emulator, tmp_path):
    """Against two emulators in lockstep (noise off), the master stepping the FMUs and the compiled loop write the same
    results.csv, every column to the bit but the wall clock's (and the rig time's origin: two rigs' clocks), whatever
    the machine's load."""
    tables = {}
    for engine in ("fmus", "compiled"):
        rig = emulator("--lockstep", "--param", "SensorChain.noise_peak=0")
        run = run_hil if engine == "fmus" else _compiled
        tables[engine] = run(fig7_archives, rig.port, tmp_path / engine, reference=LIFT_AND_STEP,
                             **({"lockstep": True} if engine == "fmus" else {"proxy.lockstep": True})).table()
        assert f"({STEPS} on the host's DRIVE)" in rig.stop() and "STOP" in rig.output
    fmus, compiled = tables["fmus"], tables["compiled"]
    assert compiled.names == fmus.names and len(compiled["time"]) == STEPS + 1
    for name in fmus.names:
        if name == "proxy.rig_time":  # two rigs' clocks: the same ticks from the first DRIVE on
            np.testing.assert_array_equal(np.round(np.diff(compiled[name][1:]) * 1e6),
                                          np.round(np.diff(fmus[name][1:]) * 1e6))
        elif name in SET_UP_BACKLOG:  # the same in the loop (the stream before the first DRIVE: as the machine's load)
            np.testing.assert_array_equal(compiled[name][1:] - compiled[name][1], fmus[name][1:] - fmus[name][1])
        elif name not in WALL_CLOCK:
            np.testing.assert_array_equal(compiled[name], fmus[name], err_msg=name)
    assert fmus["proxy.measured_height"].max() > 130e-6  # the loop lifted the object and stepped it


@pytest.mark.realtime
def test_on_the_rigs_clock_through_the_cli(fig7_archives, emulator, tmp_path, capsys):
    """`nfal run fig7_hil --compiled` against the emulator on its own clock: every step, the real-time report of the
    compiled loop, and every command the Python law's on what the loop measured."""
    rig = emulator()
    out = tmp_path / "run"
    # a generous missed-sample limit: this test is about what the loop computes, not how late a loaded machine's
    # emulator answers (the emulator runs the rig's default watchdog)
    assert main(["run", str(fig7_archives["fig7_hil"]), "--compiled", "--param", f"proxy.port={rig.port}",
                 "--param", "proxy.max_missed_samples=400", "--stop-time", "1.5", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert "STOP" in rig.stop()
    assert summary["status"] == "ok" and summary["steps_completed"] == 3000
    assert summary["realtime"]["engine"] == "compiled" and summary["realtime"]["steps"] == 3000
    assert summary["metrics"]
    table = read_results(out / "results.csv")
    dropped = table["proxy.frames_dropped"]
    assert dropped[-1] == dropped[0]  # nothing dropped in the loop (before it: SET_UP_BACKLOG)
    np.testing.assert_array_equal(table["Controller.excitation_command"],
                                  _controller_slave_on(fig7_archives["fig7_hil"], table))


def _controller_slave_on(structure, table) -> list:
    """The Controller FMU's slave (Python), set up from ``structure`` and stepped on the recorded reference and
    measurements: its command at every row."""
    with read_ssp(structure) as read:
        element = next(e for e in resolve(read).elements if e.name == "Controller")
    slave = Controller(instance_name="Controller")
    for name, value in element.start_values.items():
        setattr(slave, name, value)
    references, heights = table["Controller.reference"], table["proxy.measured_height"]
    slave.setup_experiment(0.0)
    slave.enter_initialization_mode()
    slave.reference = references[0]
    slave.exit_initialization_mode()
    commands = []
    for k, (reference, height) in enumerate(zip(references, heights)):
        slave.reference, slave.measured_height = reference, height
        commands.append(slave.value("excitation_command"))
        slave.do_step(k * 5e-4, 5e-4)
    return commands


@pytest.mark.realtime
@pytest.mark.parametrize("signal_number", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_a_stop_signal_ends_the_compiled_loop_keeps_every_row_and_says_stop(fig7_archives, emulator, tmp_path,
                                                                             signal_number):
    rig = emulator()
    out = tmp_path / "run"
    process = popen([sys.executable, "-m", "nfal", "run", str(fig7_archives["fig7_hil"]), "--compiled",
                     "--param", f"proxy.port={rig.port}", "--stop-time", "30", "--out", str(out),
                     "--no-plot"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    results = out / "results.csv"
    deadline = time.monotonic() + 60
    while not (results.is_file() and results.stat().st_size > 100_000) and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(signal_number)
    _, errors = process.communicate(timeout=60)
    assert process.returncode == 128 + signal_number, errors
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["steps_completed"] < 60_000
    assert len(read_results(results)["time"]) == summary["steps_completed"] + 1
    assert "STOP: session ended" in rig.stop()


@pytest.mark.realtime
def test_a_lost_link_ends_the_compiled_loop_with_the_reason_and_every_row(fig7_archives, emulator, tmp_path):
    """The cable pulled 1 s into the loop and never put back: the run fails naming why (the port's error, or the
    silence beyond the missed-sample limit), keeps a row for every step it completed, and the rig's watchdog ramps
    the drive down."""
    rig = emulator("--disconnect-at", "1.0", "--reconnect-after", "never")
    reference = Staircase((60e-6, 80e-6), hold_s=3.0, lead_s=0.5)
    with pytest.raises(SimulationError, match="compiled loop: .*(no measurement from the rig|the port failed)") as \
            failure:
        _compiled(fig7_archives, rig.port, tmp_path / "run", reference=reference, **{"proxy.max_missed_samples": 400})
    result = failure.value.result
    assert result.summary["status"] == "failed" and 1000 < result.summary["steps_completed"] < 7000
    rows = (tmp_path / "run" / "results.csv").read_text().splitlines()
    assert len(rows) == 1 + 1 + result.summary["steps_completed"]  # header, the initial row, one per completed step
    time.sleep(0.5)  # the rig's watchdog needs 100 ms and its ramp 50 ms after the last DRIVE
    log = rig.stop()
    assert "port disconnected" in log and "drive down: 0 V" in log


@pytest.mark.slow
def test_a_structure_other_than_fig7_hils_pair_is_refused_before_anything_opens(fig7_archives, tmp_path):
    with pytest.raises(UnsupportedFeatureError, match="a Controller and a HardwareProxy wired as fig7_hil"):
        run_compiled(fig7_archives["fig7_slow"], reference=LIFT_AND_STEP, stop_time=0.1, out_dir=tmp_path / "run")
    assert not (tmp_path / "run").exists()
