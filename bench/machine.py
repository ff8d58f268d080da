"""The machine line every benchmark prints (CPU model, cores, Python version). The time the hypervisor took from this
virtual machine (steal) is nfal.realtime.steal_s, which the real-time loops report too."""

from __future__ import annotations

import os
import platform


def describe() -> str:
    cpu = "unknown CPU"
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as handle:
            cpu = next(line.split(":", 1)[1].strip() for line in handle if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{cpu}, nproc = {os.cpu_count()}, Python {platform.python_version()}"
