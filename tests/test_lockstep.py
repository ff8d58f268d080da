"""Lockstep: the emulated rig ticks on the host's DRIVE commands and the host waits for each answer
(``nfal rig-emulator --lockstep``, ``proxy.lockstep``, :meth:`RigLink.wait_applied`), so a loaded machine cannot change
the loop. The emulator runs in a thread here, on a pty, with a rig that holds still."""

from __future__ import annotations

import threading
import time
import types

import pytest
from helpers.rig import StillRig

from nfal.apps import rig_emulator
from nfal.errors import InvalidParameterError
from nfal.hil.link import RigLink
from nfal.hil.ports import PtyPort
from nfal.hil.protocol import Drive, FrameEncoder, Hello, HostHeartbeat

PERIOD_US = 500


@pytest.fixture
def rig(tmp_path):
    """A lockstep emulator running in a thread; yields it and its events."""
    import nfal.apps.rig_emulator as module

    events: list[str] = []
    emulator = module.Emulator(PtyPort(tmp_path / "rig"), StillRig(), on_event=events.append, lockstep=True)
    thread = threading.Thread(target=emulator.run, daemon=True)
    thread.start()
    yield emulator, events
    emulator.stop()
    thread.join(5)
    emulator.port.close()


@pytest.fixture
def host(rig):
    link = RigLink(str(rig[0].port.path), reader_thread=False, connect_timeout_s=2.0)
    link.open()
    assert link.wait_until(lambda: link.latest() is not None, 2.0)
    yield link
    link.close(stop=False)


def test_each_drive_is_answered_by_one_tick_and_the_rig_waits_for_the_next(rig, host):
    emulator, _ = rig
    answers = []
    for volts in range(10, 60):
        assert host.send_drive(float(volts))
        assert host.wait_applied(2.0)
        answers.append(host.latest().measurement)
    assert [m.drive_voltage for m in answers] == [float(v) for v in range(10, 60)]
    assert {b.timestamp_us - a.timestamp_us for a, b in zip(answers, answers[1:])} == {PERIOD_US}  # one tick each
    count = host.latest().count
    time.sleep(0.1)  # 200 periods of wall time: a rig on its own clock would have sent 200 samples
    host.poll()
    assert host.latest().count == count
    assert emulator.report.lockstep_ticks == 49  # the first DRIVE arms the rig in a tick on the wall clock


def test_a_host_that_let_the_port_fill_still_gets_the_answer_to_its_first_drive(rig, host, monkeypatch):
    """Before the first DRIVE the rig streams on its own clock; a host busy setting up (or descheduled between taking
    in that backlog and sending its DRIVE) finds the port full, the last frame in it cut. The answer must still come,
    whole: the rig waits for room for it and starts it with a delimiter. (A CI run under load lost it: the proxy
    waited its 2 s for an answer the rig had dropped, while the rig waited for the next DRIVE.)"""
    emulator, _ = rig
    deadline = time.monotonic() + 30
    while emulator.port.bytes_dropped == 0 and time.monotonic() < deadline:  # the port full, nothing read
        time.sleep(0.01)
    assert emulator.port.bytes_dropped > 0
    monkeypatch.setattr(host, "drain", lambda: None)  # the DRIVE goes with the backlog unread
    assert host.send_drive(33.0)
    assert host.wait_applied(3.0)  # without the fix: only after the rig's LOCKSTEP_WAIT_S (5 s) on the wall clock
    assert host.latest().measurement.drive_voltage == 33.0
    assert host.decoder.counters.crc_errors <= 1  # the cut frame alone


def test_a_host_gone_silent_hands_the_rig_back_to_the_wall_clock_and_its_watchdog(rig, host, monkeypatch):
    import nfal.apps.rig_emulator

    emulator, events = rig
    monkeypatch.setattr(nfal.apps.rig_emulator, "LOCKSTEP_WAIT_S", 0.3)  # read at each wait
    assert host.send_drive(40.0) and host.wait_applied(2.0)
    deadline = time.monotonic() + 5
    while not any("drive down: 0 V" in event for event in events) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert any("lockstep: no DRIVE for 0.3 s, ticking on the wall clock" in event for event in events)
    assert any("watchdog: no DRIVE" in event for event in events)  # the rig ramps the drive down as ever


def test_wait_applied_gives_up_when_no_answer_comes(rig, host):
    emulator, _ = rig
    emulator.stop()  # the rig's clock stops: nothing answers
    time.sleep(0.05)
    assert host.send_drive(10.0)
    started = time.monotonic()
    assert not host.wait_applied(0.2)
    assert 0.19 < time.monotonic() - started < 2.0


def test_lockstep_refuses_a_firmware_on_its_own_serial_line(tmp_path):
    """The emulator cannot see the host's DRIVEs on a line it does not read (the C firmware's own pty, QEMU's UART0):
    lockstep takes the firmware's tunnel mode (the CLI starts it so: tests/test_hil_end_to_end.py)."""
    own_line = types.SimpleNamespace(tunnel=False, on_event=None)
    with pytest.raises(InvalidParameterError, match="own serial line"):
        rig_emulator.Emulator(PtyPort(tmp_path / "rig"), StillRig(), firmware=own_line, lockstep=True)


def test_held_host_bytes_release_a_tick_on_a_command_and_reach_the_firmware_whole():
    held, encoder = rig_emulator.HostCommands(), FrameEncoder()
    hello, heartbeat, drive = encoder(Hello()), encoder(HostHeartbeat()), encoder(Drive(3.0))
    assert held.take(hello[:4]) is False and held.take(hello[4:]) is True  # a HELLO releases a tick (for its answer)
    assert held.take(heartbeat) is False  # not a command: the rig waits on
    assert held.take(drive) is True and held.drives == 1
    assert held.release() == hello + heartbeat + drive and held.release() == b""


def test_a_lockstep_proxy_counts_missed_samples_in_rig_time_so_a_paused_host_is_no_silent_rig(rig):
    """Each step's answer is the next tick: samples_missed 0, however long the host pauses between the answer's
    arrival and its own check (30 ms here, three times the proxy's 20-sample limit at 2 kHz: a CI run failed on a
    10.8 ms pause counted by the wall clock)."""
    from nfal.fmus.hardware_proxy import HardwareProxy

    slave = HardwareProxy(instance_name="proxy")
    slave.port, slave.lockstep = str(rig[0].port.path), True
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()
    link = slave._link
    answered = link.wait_applied

    def answered_then_paused(timeout_s: float) -> bool:
        came = answered(timeout_s)
        time.sleep(0.03)  # the host descheduled right after the answer arrived
        return came

    link.wait_applied = answered_then_paused
    try:
        slave.drive_voltage = 20.0
        times = []
        for k in range(8):
            slave.do_step(k * 5e-4, 5e-4)
            times.append(round(slave.rig_time * 1e6))
            assert slave.fresh and slave.samples_missed == 0 and slave.applied_voltage == 20.0
        assert {b - a for a, b in zip(times, times[1:])} == {PERIOD_US}
    finally:
        slave.terminate()


def test_a_lockstep_proxy_without_an_answer_stops_saying_what_lockstep_needs(rig):
    from nfal.errors import LinkError
    from nfal.fmus.hardware_proxy import HardwareProxy

    slave = HardwareProxy(instance_name="proxy")
    slave.port, slave.lockstep = str(rig[0].port.path), True
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()  # the session opened within the default 2 s (a busy machine's rig thread is slow)
    slave.connect_timeout = 0.3
    rig[0].stop()  # the rig's clock stops: no answer comes, as when a frame is lost on the wire
    time.sleep(0.05)
    with pytest.raises(LinkError, match="did not report the DRIVE of t = 0 s applied within connect_timeout = 0.3 s"
                       ".*lockstep needs every frame"):
        slave.do_step(0.0, 5e-4)
    slave.terminate()
