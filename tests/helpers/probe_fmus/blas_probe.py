"""Test slave: its output is the OPENBLAS_NUM_THREADS its process has (0: none)."""
import os

from nfal.fmus.base import NfalSlave


class BlasProbe(NfalSlave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.add_output("blas_threads", unit="1", description="OPENBLAS_NUM_THREADS",
                        getter=lambda: float(os.environ.get("OPENBLAS_NUM_THREADS", 0)))

    def setup(self):
        pass

    def step(self, current_time, step_size):
        pass
