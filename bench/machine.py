"""The machine line every benchmark prints (CPU model, cores, Python version), and the time the hypervisor took from
this virtual machine (steal)."""

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


def steal_s() -> float | None:
    """CPU time the hypervisor has taken from this machine's vCPUs since boot [s] (/proc/stat's steal, summed over the
    vCPUs); None where the system does not say. A difference over a run is what no process here could have used."""
    try:
        with open("/proc/stat", encoding="utf-8") as handle:
            fields = handle.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None
