"""``nfal identify`` against ``nfal rig-emulator`` on a pty: a short identification recovers the default truth and the
design on it lifts the object off and tracks steps on the rig, and a link pulled mid-experiment stops it with the
reason, the data kept; a stop signal ramps the drive down and says STOP; a second host is refused.

What the identification measures is judged in lockstep (``--lockstep``: the rig ticks on the host's DRIVEs, so a loaded
machine cannot change it: on the wall clock, with a CPU-bound process beside it, the host once sent no DRIVE for 107 ms
and tripped the rig's 100 ms watchdog); the stop paths are tested on the wall clock. How well the host keeps the rig's
watchdog is measured by ``python bench/realtime.py identify``; a trip stops an identification
(tests/test_identification.py)."""

from __future__ import annotations

import json
import signal
import time

import numpy as np
import pytest
from helpers.rig import run_hil, simulate_the_truth
from helpers.warm_nfal import WarmProcess

from nfal.cli import main
from nfal.apps.fig7 import HARDWARE, SIMULATED, loop_metrics
from nfal.models.calibration import calibration_from_dict, paper_calibration
from nfal.models.reference import Staircase
from nfal.models.plant import ExcessDamping, SimplifiedPlant
from nfal.models.rig import RigParameters


SHORT = ("--damping-heights", "60e-6,180e-6", "--steps", "2")


@pytest.mark.slow
def test_identify_recovers_the_emulators_truth_and_its_design_holds_the_rig(fig7_archives, emulator, tmp_path):
    rig = emulator("--lockstep")
    out = tmp_path / "rig.json"
    assert main(["identify", "--port", rig.port, "--out", str(out), *SHORT]) == 0
    document = json.loads(out.read_text())
    assert document["provenance"]["port"] == rig.port and document["provenance"]["raw_data"] == "rig-raw.csv"
    assert document["provenance"]["rig_time_s"] < 60
    assert (tmp_path / "rig.png").stat().st_size > 10_000
    assert sum(1 for _ in open(tmp_path / "rig-raw.csv")) > 10_000
    truth, model = (SimplifiedPlant(RigParameters(), K) for K in (paper_calibration(), calibration_from_dict(document)))
    for height in np.linspace(50e-6, 200e-6, 16):
        assert model.equilibrium_height(float(truth.equilibrium_excitation(height))) == pytest.approx(height, rel=0.01)
    damping = document["damping"]
    truth_factors = ExcessDamping.rig_like().factor(np.array(damping["heights_m"]))
    np.testing.assert_allclose(damping["factors"], truth_factors, rtol=0.15)
    log = rig.stop()
    assert "STOP: session ended" in log and "watchdog:" not in log  # the host ramped down and said STOP
    # the loop on the rig with the identified design, from rest (a fresh emulator: each plays at most 60 s), in lockstep
    # so that the machine's load cannot change the loop (paced on the wall clock at 1 kHz the first step overshot 6.4 %
    # where the simulation gave 0.0 %: in lockstep both steps overshoot 0.000 %, as simulated)
    rig = emulator("--lockstep", "--param", "SensorChain.noise_peak=0")
    reference = Staircase((60e-6, 140e-6, 180e-6), hold_s=0.4, lead_s=1.0)
    result = run_hil(fig7_archives, rig.port, tmp_path / "hil", reference=reference, lockstep=True,
                     **{"Controller.calibration": str(out)})
    lift_off = np.asarray(result[HARDWARE.measured])[result.table().time < reference.lead_s]
    assert lift_off.max() <= 66e-6  # the paper's law: 104-110 um (docs/hil.md)
    # each step as the same design does on the truth in simulation, within half a point (the paper's law overshoots
    # 40 % from 140 to 180 um): the identified design holds the rig as it holds the truth
    simulated = simulate_the_truth(fig7_archives, reference, tmp_path / "sim", **{"Controller.calibration": str(out)})
    on_rig, expected = (loop_metrics(run.table(), reference, columns)["steps"]
                        for run, columns in ((result, HARDWARE), (simulated, SIMULATED)))
    for step, twin in zip(on_rig, expected):
        assert step["overshoot_percent"] == pytest.approx(twin["overshoot_percent"], abs=0.5), (on_rig, expected)


@pytest.mark.slow
@pytest.mark.realtime
def test_a_link_lost_mid_experiment_stops_with_the_reason_and_keeps_the_data(emulator, tmp_path, capsys):
    # judged: the link-lost path. The rig's watchdog is 1 s here, as in the stop-signal tests below: a CI run on
    # 2026-11-27 (19:2x UTC) tripped the default 100 ms at rig time 0.87 s (a 154 ms gap between DRIVEs in the test
    # worker's process) before the disconnect at 2 s; the margin to the default is `python bench/realtime.py identify`
    rig = emulator("--disconnect-at", "2", "--reconnect-after", "never", "--watchdog", "1.0")
    out = tmp_path / "rig.json"
    assert main(["identify", "--port", rig.port, "--out", str(out), *SHORT]) == 2
    error = capsys.readouterr().err
    assert "link lost" in error and "the rig's watchdog does" in error and "every sample so far is in" in error
    assert not out.exists()
    assert sum(1 for _ in open(tmp_path / "rig-raw.csv")) > 2000  # 2 s at 2 kHz, less what a loaded host missed
    assert "port disconnected" in rig.stop()


def _lines(path) -> int:
    try:
        with open(path, "rb") as handle:
            return sum(chunk.count(b"\n") for chunk in iter(lambda: handle.read(1 << 16), b""))
    except FileNotFoundError:
        return 0


@pytest.mark.slow
@pytest.mark.realtime
@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGHUP"])
def test_a_stop_signal_ramps_the_drive_down_says_stop_and_keeps_every_sample(emulator, tmp_path, capsys, signal_name):
    """`timeout`, `kill`, systemd or a closed terminal: the identification stops at the next exchange, ramps the drive
    down, says STOP and keeps every sample; meanwhile a second host on the same port is refused and the first runs
    on."""
    record = tmp_path / "rig-record.csv"
    # judged: the stop path. The rig's watchdog is 1 s here, not 100 ms: on this machine since 2026-11-25 20:00 UTC the
    # identification's gaps between DRIVEs reach 171-175 ms once in a few runs (issue 23's note), a trip this test would
    # report instead of the signal; the margin to the default watchdog is measured by
    # `python bench/realtime.py identify`
    rig = emulator("--record", str(record), "--watchdog", "1.0")
    raw = tmp_path / "rig-raw.csv"
    host = WarmProcess(["identify", "--port", rig.port, "--out", str(tmp_path / "rig.json")])
    deadline = time.monotonic() + 120  # a bound for a broken run, not a measure: the test waits for rig time
    while _lines(raw) < 4000 and host.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert main(["identify", "--port", rig.port, "--out", str(tmp_path / "second.json")]) == 2
    assert "in use by another program" in capsys.readouterr().err and not (tmp_path / "second-raw.csv").exists()
    assert host.poll() is None, host.communicate()[1]  # the first host ran on
    host.send_signal(getattr(signal, signal_name))
    _, errors = host.communicate(timeout=60)
    assert host.returncode == 128 + getattr(signal, signal_name), errors
    assert f"interrupted by {signal_name}; the drive ramped down; STOP sent; every sample so far is in" in errors
    log = rig.stop()
    assert "STOP: session ended" in log and "watchdog:" not in log
    rows = np.genfromtxt(raw, delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert rows["commanded_voltage_v"][-1] == 0.0  # ramped down, then STOP
    # the rig applied 0 V at the end of the ramp (its last frame may not reach the host before the port closes)
    sent = np.genfromtxt(record, delimiter=",", names=True)  # every measurement the rig sent in the session
    assert sent["applied_voltage_v"][-1] == 0.0
    # every sample the rig sent is kept, up to the last the host read (those in flight when it closed the port, a few
    # ms on a loaded machine, are not), and that last one is within 0.1 s of the rig's last
    kept = set(np.round(rows["rig_time_s"] * 1e6).astype(int))
    sent_us = np.round(sent["timestamp_us"]).astype(int)
    assert all(t in kept for t in sent_us if t <= max(kept))
    assert sent_us[-1] - max(kept) < 100_000
