"""Test slave: how many Python thread states have stepped it (a threading.local lives as long as
one) and how many the interpreter holds while it steps (the stepping thread's own included): outputs of its
state, which the runtime's value cache holds from the end of each step."""
import ctypes
import threading

from nfal.fmus.base import NfalSlave

api = ctypes.pythonapi
api.PyInterpreterState_Get.restype = ctypes.c_void_p
api.PyInterpreterState_ThreadHead.restype = api.PyThreadState_Next.restype = ctypes.c_void_p
api.PyInterpreterState_ThreadHead.argtypes = api.PyThreadState_Next.argtypes = [ctypes.c_void_p]


def interpreter_thread_states():
    count, state = 0, api.PyInterpreterState_ThreadHead(api.PyInterpreterState_Get())
    while state:
        count, state = count + 1, api.PyThreadState_Next(state)
    return count


class ThreadStateProbe(NfalSlave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._local, self._stepped_by = threading.local(), 0
        self.add_output("stepped_by", unit="1", description="Python thread states that stepped this instance")
        self.add_output("held", unit="1", description="Python thread states the interpreter holds while it steps")

    def setup(self):
        pass

    def step(self, current_time, step_size):
        if not getattr(self._local, "seen", False):
            self._local.seen = True
            self._stepped_by += 1
        self.stepped_by, self.held = float(self._stepped_by), float(interpreter_thread_states())
