"""The rig for the HIL tests: ``nfal rig-emulator`` in a process of its own (:class:`Emulator`; the ``emulator``
fixture in conftest.py starts them on the session's rig_slow.ssp), fig7_hil run against it (:func:`run_hil`), the
simulation of the same truth it is judged against (:func:`simulate_the_truth`), and a rig model that holds still
(:class:`StillRig`)."""

from __future__ import annotations

from subprocess import TimeoutExpired

from nfal.models.reference import Staircase
from nfal.orchestration import run_structure
from nfal.orchestration.pacing import realtime_priority_refusal

from helpers.warm_nfal import WarmProcess

#: The truth of rig_truth.ssv, as parameters of fig7_slow's Plant: the same model, simulated.
TRUTH = {"Plant.initial_height": 5e-6, "Plant.excess_damping_height": 137e-6, "Plant.excess_damping_exponent": 6.0,
         "Plant.near_surface": "fast"}
#: A step from 100 um to 140 um after 1 s of lift-off and hold.
STEP = Staircase((100e-6, 140e-6), hold_s=1.0, lead_s=1.0)
#: SCHED_FIFO priority of the emulator (the rig), where the system allows it.
RT_PRIORITY = 50


class Emulator:
    """`nfal rig-emulator` in a process of its own, forked from a warm one (helpers/warm_nfal.py): its port (first
    line) and, after stop(), the rest of its output. It stands for the rig, a separate machine with its own
    processor: where the system allows it, it runs under SCHED_FIFO, so that the test process beside it (the host,
    at normal priority) cannot starve it."""

    def __init__(self, truth, *options: str) -> None:
        priority = () if realtime_priority_refusal(RT_PRIORITY) else ("--rt-priority", str(RT_PRIORITY))
        self.process = WarmProcess(["rig-emulator", "--truth", str(truth), "--duration", "60", *priority, *options])
        self.port = self.process.stdout.readline().strip()
        if not self.port:
            self.process.kill()
            raise RuntimeError(f"the emulator did not start: {self.process.communicate()[1]}")
        self.output = ""

    def stop(self) -> str:
        if self.process.poll() is None:
            self.process.terminate()
        try:
            self.output, errors = self.process.communicate(timeout=20)
        except TimeoutExpired:
            self.process.kill()
            raise
        return self.output


def run_hil(fig7_archives, port: str, out, reference=STEP, lockstep=False, **parameters):
    """fig7_hil on the rig at ``port``: paced on the wall clock; or, with ``lockstep`` (the emulator started with
    ``--lockstep``), unpaced, each step waiting for the rig's answer (``proxy.lockstep``), so that the loop does not
    depend on the machine's load."""
    if lockstep:
        parameters = {"proxy.lockstep": True, **parameters}
    return run_structure(fig7_archives["fig7_hil"], stop_time=reference.duration_s,
                         inputs={"Controller.reference": reference}, parameters={"proxy.port": port, **parameters},
                         realtime=not lockstep, plot=False, out_dir=out)


def simulate_the_truth(fig7_archives, reference, out, **parameters):
    """fig7_slow on the emulator's truth (TRUTH, noise off): the simulation a HIL run of the same reference is judged
    against."""
    return run_structure(fig7_archives["fig7_slow"], stop_time=reference.duration_s,
                         inputs={"Controller.reference": reference}, plot=False, out_dir=out,
                         parameters={**TRUTH, "SensorChain.noise_peak": 0.0, **parameters})


class StillRig:
    """A rig model that holds the object at 100 um (the emulator's model interface)."""

    true_height = 100e-6

    def apply(self, voltage: float) -> None:
        self.voltage = voltage

    def reading(self):
        from nfal.hil.firmware import RigReading

        return RigReading(self.true_height, 28_500.0, True, False)

    def advance(self) -> None:
        pass
