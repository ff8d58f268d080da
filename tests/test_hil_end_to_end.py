"""Hardware in the loop, end to end: `nfal rig-emulator` in a subprocess on a pty, fig7_hil run in real time.

Each test starts the emulator on the session's built rig_slow.ssp (the truth: the slow plant with the
large-gap damping of rig_truth.ssv, the resonance tracker, the sensor chain) and runs the HIL structure
(the unchanged Controller and the HardwareProxy) paced on the wall clock.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import time

import numpy as np
import pytest

from nfal.cli import main
from nfal.fig7 import HARDWARE, PROXY, SIMULATED, loop_metrics
from nfal.models.closed_loop import Staircase
from nfal.orchestration import SimulationError, run_structure
from nfal.orchestration.pacing import realtime_priority_refusal

pytestmark = pytest.mark.realtime

#: The truth of rig_truth.ssv, as parameters of fig7_slow's Plant: the same model, simulated.
TRUTH = {"Plant.initial_height": 5e-6, "Plant.excess_damping_height": 137e-6, "Plant.excess_damping_exponent": 6.0,
         "Plant.near_surface": "fast"}
#: A step from 100 um to 140 um after 1 s of lift-off and hold.
STEP = Staircase((100e-6, 140e-6), hold_s=1.0, lead_s=1.0)
#: Where the step's transient is compared [s].
TRANSIENT = (1.0, 1.2)
#: SCHED_FIFO priority of the emulator (the rig), where the system allows it.
RT_PRIORITY = 50
#: The host's missed-sample limit where a lost link is the point of the test: 50 ms.
MISSED = 100
#: The rate of the tests that judge the loop's response on the wall clock [Hz]. At 2 kHz the host's step (its
#: HardwareProxy's doStep alone 172 us on average) leaves too little of the 500 us period on this 2-core machine: the
#: loop overran 36 % of its steps (2026-11-26, with the emulator's tick at 90 us since its plant is compiled; before,
#: the emulator's tick took 420-500 us of its 500 too), and the step test passed 2 of 4 runs at 2 kHz. So those tests
#: run host and rig at 1 kHz, with the filter scaled to keep the sampled loop's dynamics (6 of 6 passed, 2026-11-26);
#: the others run at Table 2's 2 kHz.
JUDGED_RATE = 1000.0


class Emulator:
    """`nfal rig-emulator` as a subprocess: its port (first line) and, after stop(), the rest of its output. It stands
    for the rig, a separate machine with its own processor: where the system allows it, it runs under SCHED_FIFO, so
    that the test process beside it (the host, at normal priority unless a test says otherwise) cannot starve it."""

    def __init__(self, truth, *options: str) -> None:
        priority = () if realtime_priority_refusal(RT_PRIORITY) else ("--rt-priority", str(RT_PRIORITY))
        self.process = subprocess.Popen([sys.executable, "-m", "nfal", "rig-emulator", "--truth", str(truth),
                                         "--duration", "60", *priority, *options], stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, text=True)
        self.port = self.process.stdout.readline().strip()
        if not self.port:
            self.process.kill()
            raise RuntimeError(f"the emulator did not start: {self.process.communicate()[1]}")
        self.output = ""

    def stop(self) -> str:
        if self.process.poll() is None:
            self.process.terminate()
        self.output, errors = self.process.communicate(timeout=20)
        return self.output


@pytest.fixture
def emulator(fig7_archives):
    started = []

    def start(*options: str) -> Emulator:
        started.append(Emulator(fig7_archives["rig_slow"], *options))
        return started[-1]

    yield start
    for process in started:
        process.stop()


def _controller_at(rate: float, reference) -> dict:
    """The Controller sampling at ``rate`` [Hz], its filter scaled with it (Table 2's T_s omega_L = 0.94), designed
    over ``reference``'s levels only (at 1 kHz the 10 Hz cut-off is out of reach at 190 um)."""
    return {"Controller.sample_rate": rate, "Controller.filter_cutoff": 300.0 * rate / 2000.0,
            "Controller.reference_min": min(reference.levels_m), "Controller.reference_max": max(reference.levels_m)}


def _hil(fig7_archives, port: str, out, reference=STEP, rt_priority=None, rate=None, **parameters):
    """fig7_hil on the rig at ``port``, paced; ``rate`` [Hz]: the host and the rig (started with ``--sample-rate``) at
    that rate, the Controller's filter scaled with it, so the sampled loop's dynamics are Table 2's
    (T_s omega_L = 0.94)."""
    step_size = None
    if rate is not None:
        step_size = 1.0 / rate
        parameters = {"proxy.sample_rate": rate, **_controller_at(rate, reference), **parameters}
    return run_structure(fig7_archives["fig7_hil"], stop_time=reference.duration_s, step_size=step_size,
                         inputs={"Controller.reference": reference}, parameters={"proxy.port": port, **parameters},
                         realtime=True, plot=False, out_dir=out, rt_priority=rt_priority)


def simulate_the_truth(fig7_archives, reference, out, **parameters):
    """fig7_slow on the emulator's truth (TRUTH, noise off) at JUDGED_RATE, set up as :func:`_hil` sets up the host
    and ``--sample-rate`` the rig: the simulation a HIL run of the same reference is judged against."""
    rate = {**_controller_at(JUDGED_RATE, reference), "SensorChain.sample_rate": JUDGED_RATE,
            "ResonanceTracker.pll_rate": JUDGED_RATE}
    return run_structure(fig7_archives["fig7_slow"], stop_time=reference.duration_s, step_size=1.0 / JUDGED_RATE,
                         inputs={"Controller.reference": reference}, plot=False, out_dir=out,
                         parameters={**TRUTH, **rate, "SensorChain.noise_peak": 0.0, **parameters})


def _kept_up(result, start: float, end: float, samples: int = 4) -> bool:
    """Over [start, end): no gap of more than ``samples`` rig samples, and the rig's clock in step with the host's
    (its lag behind the host's time varies by at most as long). Not so when the machine stalled one of the two
    processes (the rig gives up the time it stalled; the host catches up in a burst)."""
    t = result.table().time
    window = (t >= start) & (t < end)
    lag = (t - np.asarray(result[f"{PROXY}.rig_time"]))[window]
    return bool(np.max(np.asarray(result[f"{PROXY}.samples_missed"])[window]) <= samples
                and np.ptp(lag) <= samples / JUDGED_RATE)


@pytest.mark.slow
def test_hil_tracks_a_step_like_the_simulation_of_the_truth(fig7_archives, emulator, tmp_path):
    """Noise off on both sides. The HIL loop has the link's delay (up to a sample or two) that the simulated loop
    has not, and lifts off from rest at a different phase, so the comparison starts after lift-off (0.5 s).
    Tolerances (measured at 2 kHz: 1.6 um, 0 um, 2 ms, 0.4 points): the step's transient within 5 um; the last half of
    each hold within 0.05 um; rise time within 5 ms; overshoot within 3 percentage points.

    The host runs under SCHED_FIFO where the system allows it, as the rig does, with the rig's default watchdog. This
    shared 2-core virtual machine pauses processes for tens of milliseconds now and then (docs/hil.md, "Real time that
    holds"), and a pause during the step changes the loop's transient as it would on a real rig, so a run whose link did
    not keep real time during the step (:func:`_kept_up`) is not judged but repeated, up to three times. This retry is a
    known defect of the test (issue 23: HIL tests should judge in rig time), kept until the comparison is made against a
    simulation driven by what the rig actually applied."""
    priority = None if realtime_priority_refusal(RT_PRIORITY) else RT_PRIORITY
    for attempt in range(3):
        rig = emulator("--param", "SensorChain.noise_peak=0", "--sample-rate", str(JUDGED_RATE))
        hil = _hil(fig7_archives, rig.port, tmp_path / f"hil{attempt}", rt_priority=priority, rate=JUDGED_RATE,
                   **{"proxy.max_missed_samples": 2000})
        assert "HELLO: session open" in rig.stop()
        if _kept_up(hil, *TRANSIENT):
            break
    else:
        pytest.fail(f"the link did not keep real time during the step in any of 3 runs: {hil.summary['realtime']}")
    simulated = simulate_the_truth(fig7_archives, STEP, tmp_path / "sim")
    t = hil.table().time
    measured, expected = np.asarray(hil[HARDWARE.measured]), np.asarray(simulated[SIMULATED.measured])
    difference = np.abs(measured - expected)
    transient = (t >= TRANSIENT[0]) & (t < TRANSIENT[1])
    # the step's transient as the simulation's, up to the link's delay (0-2 samples): measured at 1 kHz, 2.4-3.7 um at
    # the best delay in 3 runs that kept real time (3.7-4.8 um at none)
    assert min(np.max(np.abs(measured - np.roll(expected, lag))[transient]) for lag in range(3)) < 5e-6
    for start, end in ((0.5, 1.0), (1.5, 2.0)):
        assert np.max(difference[(t >= start) & (t < end)]) < 0.05e-6
    [hil_step] = loop_metrics(hil.table(), STEP, HARDWARE)["steps"]
    [sim_step] = loop_metrics(simulated.table(), STEP, SIMULATED)["steps"]
    assert hil_step["rise_time_s"] == pytest.approx(sim_step["rise_time_s"], abs=5e-3)
    assert hil_step["overshoot_percent"] == pytest.approx(sim_step["overshoot_percent"], abs=3.0)
    realtime = hil.summary["realtime"]
    assert realtime["steps"] == round(STEP.duration_s * JUDGED_RATE)
    assert {"jitter_p50_s", "jitter_p99_s", "jitter_max_s", "overruns"} <= set(realtime)


@pytest.mark.slow
def test_corrupted_dropped_and_duplicated_frames_are_counted_and_never_used(fig7_archives, emulator, tmp_path, capsys):
    """Through the CLI: the run completes; every (rig time, height) in results.csv is one the rig measured."""
    record = tmp_path / "rig.csv"
    rig = emulator("--corrupt", "0.05", "--drop", "0.05", "--duplicate", "0.05", "--seed", "3", "--record", str(record))
    out = tmp_path / "run"
    # a generous missed-sample limit: this test is about what reaches the host, not about how late (a starved
    # emulator on a loaded machine was once silent for 11 ms, above the default 10 ms)
    assert main(["run", str(fig7_archives["fig7_hil"]), "--param", f"proxy.port={rig.port}", "--param",
                 "proxy.max_missed_samples=400", "--stop-time", "1.5", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    rig.stop()
    assert summary["status"] == "ok" and summary["realtime"]["steps"] == 3000
    link = summary["link"]
    assert link["frames_dropped"] > 0 and link["frames_lost"] > 0  # corrupted + duplicated; dropped
    with record.open() as handle:
        measured = {(int(row["timestamp_us"]), np.float32(float(row["height_m"])))
                    for row in csv.DictReader(handle)}
    with (out / "results.csv").open() as handle:
        used = {(round(float(row["proxy.rig_time [s]"]) * 1e6), np.float32(float(row["proxy.measured_height [m]"])))
                for row in csv.DictReader(handle)}
    assert used and used <= measured


@pytest.mark.slow
def test_a_disconnect_stops_the_run_keeps_the_rows_and_the_watchdog_ramps_down(fig7_archives, emulator, tmp_path):
    # the disconnect comes 1 s of rig time after the host's HELLO, which precedes the Controller's set-up (0.4 s idle,
    # 1.5 s at load 6): the loop has run a little or a lot by then, and would run 3.5 s without it
    rig = emulator("--disconnect-at", "1.0", "--reconnect-after", "never")
    with pytest.raises(SimulationError, match="no measurement from the rig") as failure:
        _hil(fig7_archives, rig.port, tmp_path / "run", reference=Staircase((60e-6, 80e-6), hold_s=3.0, lead_s=0.5),
             **{"proxy.max_missed_samples": MISSED})  # above a starved emulator's silences (11 ms seen at load 6)
    result = failure.value.result
    assert "link lost" in result.summary["error"]
    assert result.summary["status"] == "failed"
    completed = result.summary["steps_completed"]
    # the run stepped with fresh measurements until the disconnect and stopped within the missed-sample limit
    # (MISSED) of the last one: counted in steps after it, not in wall time (the host's initialisation and a loaded
    # machine move the disconnect within the run)
    fresh = np.flatnonzero(result.table()["proxy.fresh"] > 0)
    assert fresh.size > 10
    assert completed - fresh[-1] <= 2 * MISSED + 5  # the limit, and as many stale steps before it
    rows = (tmp_path / "run" / "results.csv").read_text().splitlines()
    assert len(rows) == 1 + 1 + completed  # header, the initial row, one per completed step
    time.sleep(0.5)  # the rig's watchdog needs 200 ms and its ramp 50 ms after the last DRIVE
    log = rig.stop()
    assert "port disconnected" in log and "watchdog: no DRIVE" in log and "drive down: 0 V" in log


@pytest.mark.slow
def test_a_short_disconnect_is_ridden_through_by_reconnecting(fig7_archives, emulator, tmp_path):
    """With the missed-sample limit above the outage the link reconnects and the run completes."""
    rig = emulator("--disconnect-at", "0.5", "--reconnect-after", "0.05")
    result = _hil(fig7_archives, rig.port, tmp_path / "run",
                  reference=Staircase((60e-6, 80e-6), hold_s=0.8, lead_s=0.7), **{"proxy.max_missed_samples": 2000})
    table = result.table()
    assert result.summary["status"] == "ok"
    assert table["proxy.reconnects"][-1] == 1
    assert np.max(table["proxy.samples_missed"]) > 50  # the outage, seen as missed samples
    assert "port reconnected" in rig.stop()


@pytest.mark.slow
def test_libcosim_runs_the_hil_structure_against_the_emulator(fig7_archives, emulator):
    """An independent master (OSP libcosim, its real-time mode) runs the proxy FMU against the rig's default 20 ms
    watchdog: the proxy holds the real-time discipline itself, whatever master steps it. Judged in the rig's samples
    (in order, none missed beyond the proxy's limit) and the levels reached, not in wall-clock windows (a rig stalled by
    a loaded machine gives the stalled time up: its clock may advance less than the run's)."""
    from nfal.orchestration.libcosim import run_ssp

    rig = emulator()
    reference = Staircase((60e-6, 100e-6), hold_s=0.8, lead_s=0.7)
    run = run_ssp(fig7_archives["fig7_hil"], stop_time=reference.duration_s, inputs={"Controller.reference": reference},
                  parameters={"proxy.port": rig.port, "proxy.max_missed_samples": 400}, realtime=True)
    assert "watchdog: no DRIVE" not in rig.stop()
    height, rig_time = run.values["proxy.measured_height"], run.values["proxy.rig_time"]
    assert np.all(np.diff(rig_time) >= 0) and rig_time[-1] > rig_time[0]  # live samples, in order
    t = run.time_s
    for start, end, level in ((0.4, 0.7, 60e-6), (1.2, 1.5, 100e-6)):
        assert np.all(np.abs(height[(t >= start) & (t < end)] - level) < 5e-6)


#: Sessions of the proxy in the C host, one process each (``python bench/proxy_c_host.py`` makes the long count).
PROXY_C_HOST_RUNS = 4


@pytest.mark.slow
def test_the_proxy_in_a_c_host_talks_to_the_emulator_and_exits_cleanly(fig7_archives, emulator, tmp_path):
    """A non-Python host (fmus/hosts/fmi2_host.c) sets the proxy's port to the emulator's pty, initialises (HELLO,
    the first sample), steps 10 ms, terminates (STOP), frees and exits: every process exits with 0, each run a
    session of its own with a live measurement."""
    from nfal.errors import HostUnavailableError
    from nfal.host_check import compile_c_host, run_in_c_host

    try:
        host = compile_c_host(tmp_path)
    except HostUnavailableError as exc:
        pytest.skip(str(exc))
    rig = emulator()
    runs = run_in_c_host(host, fig7_archives["fig7_hil"].parent / "HardwareProxy.fmu", tmp_path,
                         runs=PROXY_C_HOST_RUNS, workers=1, strings={"port": rig.port})
    assert runs.exit_codes == [0] * PROXY_C_HOST_RUNS, runs.first_failure[-3000:]
    for outputs in runs.outputs:
        assert 0 < outputs["measured_height"] < 1e-3 and outputs["rig_time"] > 0
    log = rig.stop()  # the firmware's log: each process opened a session (HELLO) and ended it (STOP, fmi2Terminate)
    assert log.count("HELLO: session open") >= PROXY_C_HOST_RUNS
    assert log.count("STOP: session ended") == PROXY_C_HOST_RUNS


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"], ids=["Ctrl-C", "SIGTERM"])
def test_the_emulator_stopped_by_a_signal_reports_the_whole_run(fig7_archives, signal_name):
    import signal

    rig = Emulator(fig7_archives["rig_slow"], "--json")
    time.sleep(0.5)
    rig.process.send_signal(getattr(signal, signal_name))
    output = rig.stop()
    report = json.loads(output[output.index("{"):])  # after the event lines (if the pipe had not taken them already)
    assert rig.process.returncode == 0
    assert report["ticks"] > 500 and report["pacing"]["steps"] == report["ticks"]  # 0.5 s at 2 kHz, less start-up
    assert "dropped" in report["decoder"] and "dropped" in report["faults"]


@pytest.mark.slow
def test_compare_runs_each_controller_on_the_rig(fig7_archives, emulator, tmp_path, capsys):
    """`nfal compare --port`: one run per controller on the rig from rest, each kept, metrics as in simulation."""
    rig = emulator("--param", "SensorChain.noise_peak=0")
    runs = tmp_path / "runs"
    assert main(["compare", "--port", rig.port, "--controllers", "gs,120", "--levels", "60e-6,80e-6", "--hold", "0.3",
                 "--build-dir", str(fig7_archives["fig7_hil"].parent), "--runs-dir", str(runs),
                 "--param", f"proxy.max_missed_samples={MISSED}", "--json"]) == 0
    output = json.loads(capsys.readouterr().out)
    assert output["rig"] == rig.port and output["reference"]["lead_s"] == 1.0
    for key in ("gs", "120"):
        [step] = output["controllers"][key]["steps"]
        assert step["overshoot_percent"] < 50 and step["settling_time_s"] is not None  # 120 um's design at 60 um: 27 %
        assert (runs / key / "results.csv").is_file()


@pytest.mark.slow
def test_the_hil_loop_lifts_off_from_rest_without_passing_the_first_level_by_ten_percent(fig7_archives, emulator,
                                                                                          tmp_path):
    rig = emulator("--param", "SensorChain.noise_peak=0", "--sample-rate", str(JUDGED_RATE))
    reference = Staircase((60e-6, 70e-6), hold_s=0.2, lead_s=1.0)
    result = _hil(fig7_archives, rig.port, tmp_path / "run", reference=reference, rate=JUDGED_RATE,
                  **{"proxy.max_missed_samples": MISSED})
    lead = result.table().time < 1.0
    height = np.asarray(result[HARDWARE.measured])[lead]
    assert height[0] < 10e-6 and height.max() <= 66e-6  # from rest on the surface to the 60 um level
    assert abs(height[-1] - 60e-6) < 1e-6
