"""Test slave: the start and stop time its host declared (-1: no stop time)."""
from nfal.fmus.base import NfalSlave


class TimesProbe(NfalSlave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.add_output("declared_start", unit="s", description="the start time the host declared",
                        getter=lambda: float(self.start_time))
        self.add_output("declared_stop", unit="s", description="the stop time the host declared (-1: none)",
                        getter=lambda: -1.0 if self.stop_time is None else float(self.stop_time))

    def setup(self):
        pass

    def step(self, current_time, step_size):
        pass
