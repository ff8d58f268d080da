"""Imported by the warm fork server (:mod:`helpers.warm_nfal`): the plant's kernels compiled once, as the rig emulator
compiles them before its loop (models/jit.py), so that no forked emulator pays numba's 1.2 s."""

from nfal.models import slow_kernels

slow_kernels.load()
