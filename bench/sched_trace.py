"""What holds the compiled HIL loop's real-time threads up, seen by the kernel's scheduler (docs/hil.md).

Runs ``nfal run fig7_hil --realtime --compiled --rt-priority 50`` against ``nfal rig-emulator`` (SCHED_FIFO 50) with
ftrace recording sched_switch and sched_wakeup (the mono clock, a ring of --ring-mb per vCPU: the last minutes are
kept), stops the trace when the host exits, and reports for each real-time thread (the loop's, the emulator's): its
wake-up latency (wake-up to running) at p50 / p99 / p99.9 / max, the wake-ups that waited more than 1 ms and the task
that held the CPU meanwhile, its longest stretches on the CPU (over the trace, and in its last seconds) and its longest
sleeps in the kernel (state D: from leaving the CPU so to running again). ``--neighbour`` runs a CPU-bound process
beside. Needs root (tracefs, SCHED_FIFO).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import record
from machine import describe
from realtime import HERE, emulator, hil_command, neighbour

TRACING = Path("/sys/kernel/debug/tracing")
#: A wake-up that waited longer than this is listed with the task that held the CPU [s].
LONG_WAIT_S = 1e-3
#: The stretches on the CPU are looked at over this last part of the trace [s] (it ends when the host exits: a
#: stop's moment, and the emulator's own wind-down after the host's STOP).
LAST_S = 2.0
EVENT = re.compile(r"\s*(?P<task>.+?)-(?P<pid>\d+)\s+\[(?P<cpu>\d+)\]\s+\S+\s+(?P<ts>[\d.]+): "
                   r"(?P<ev>\w+): (?P<rest>.*)")


def field(rest: str, name: str) -> str:
    return rest.split(f"{name}=")[1].split()[0]


def tracing(on: bool, ring_mb: int = 0) -> None:
    if not TRACING.exists():
        subprocess.run(["mount", "-t", "debugfs", "none", "/sys/kernel/debug"], check=True)
    if on:
        (TRACING / "tracing_on").write_text("0")
        (TRACING / "trace").write_text("")
        (TRACING / "buffer_size_kb").write_text(str(ring_mb * 1024))
        (TRACING / "trace_clock").write_text("mono")
        (TRACING / "set_event").write_text("sched:sched_switch sched:sched_wakeup")
    (TRACING / "tracing_on").write_text("1" if on else "0")


def analyse(lines, threads: dict[str, str]) -> dict:
    """``threads``: tid -> label. Wake-up latencies, the long waits' holders, the stretches on the CPU (the longest,
    and the last ones), the longest sleeps in the kernel (state D: a syscall waiting on a lock or a worker)."""
    woken, latency, holders = {}, collections.defaultdict(list), collections.defaultdict(collections.Counter)
    running, stretches, first, end = {}, collections.defaultdict(list), {}, 0.0
    left, blocked = {}, collections.defaultdict(list)  # tid -> (when it left the CPU, its state); D sleeps
    for line in lines:
        m = EVENT.match(line)
        if not m:
            continue
        ts, cpu, rest = float(m["ts"]), m["cpu"], m["rest"]
        first.setdefault(cpu, ts)
        end = ts
        if m["ev"] == "sched_wakeup":
            if (tid := field(rest, "pid")) in threads:
                woken[tid] = ts
            continue
        if m["ev"] != "sched_switch":
            continue
        prev, nxt = field(rest, "prev_pid"), field(rest, "next_pid")
        if prev in threads and running.get(cpu, (None,))[0] == prev:
            stretches[prev].append((ts - running[cpu][1], ts))
        if prev in threads:
            left[prev] = (ts, field(rest, "prev_state"))
        if nxt in left and left[nxt][1].startswith("D"):
            blocked[nxt].append(ts - left[nxt][0])
        running[cpu] = (nxt, ts)
        if nxt in threads and nxt in woken:
            wait = ts - woken.pop(nxt)
            latency[nxt].append(wait)
            if wait > LONG_WAIT_S:
                holders[nxt][rest.split("prev_comm=")[1].split(" prev_pid=")[0]] += 1
    common = max(first.values(), default=0.0)  # both vCPUs' rings cover the trace from here
    report = {"traced_s": round(end - common, 1), "threads": {}}
    for tid, label in threads.items():
        waits = np.array(latency[tid])
        if not waits.size:
            continue
        last = sorted((d for d, at in stretches[tid] if at > end - LAST_S), reverse=True)[:5]
        on_cpu = sorted((d for d, _ in stretches[tid]), reverse=True)
        report["threads"][label] = {
            "wake_ups": waits.size,
            **{f"wake_{name}_us": round(float(percentile) * 1e6, 1) for name, percentile in
               zip(("p50", "p99", "p999"), np.percentile(waits, [50, 99, 99.9], method="higher"))},
            "wake_max_ms": round(float(waits.max()) * 1e3, 2),
            "waits_over_1ms_by_holder": dict(holders[tid].most_common()),
            "longest_stretches_ms": [round(d * 1e3, 2) for d in on_cpu[:5]],
            "stretches_over_5ms": sum(d > 5e-3 for d in on_cpu),
            "longest_blocked_in_kernel_ms": [round(d * 1e3, 2) for d in sorted(blocked[tid], reverse=True)[:5]],
            "longest_stretches_in_last_s_ms": [round(d * 1e3, 2) for d in last]}
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=120.0, help="seconds of the HIL run (default 120)")
    parser.add_argument("--ring-mb", type=int, default=64, help="trace ring per vCPU [MB] (default 64: ~100 s)")
    parser.add_argument("--neighbour", action="store_true",
                        help="a CPU-bound process at normal priority beside the run (sched-trace-neighbour.json)")
    args = parser.parse_args()
    if os.geteuid() != 0:
        sys.exit("sched_trace: needs root (tracefs and SCHED_FIFO)")
    print(describe(), flush=True)
    folder = HERE.parent / "runs" / time.strftime("sched-trace-%Y%m%d-%H%M%S")  # runs/ is ignored
    folder.mkdir(parents=True)
    threads = {}
    with neighbour(args.neighbour), emulator(folder) as (port, rig):
        command = hil_command(port, args.duration, folder / "hil", "--realtime", "--compiled", "--rt-priority", "50")
        tracing(True, args.ring_mb)
        with open(folder / "host.out", "w") as out:
            host = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
            while host.poll() is None:  # the threads' ids while they live; no process started meanwhile
                for pid, label in ((rig.pid, "emulator"), (host.pid, "host")):
                    for task in Path(f"/proc/{pid}/task").glob("*"):
                        threads.setdefault(task.name, f"{label} {task.name}")
                time.sleep(0.2)
        tracing(False)
    summary = json.loads((folder / "hil" / "summary.json").read_text())
    with open(TRACING / "trace", encoding="utf-8", errors="replace") as trace:
        report = analyse(trace, threads)
    report["threads"] = {label: value for label, value in report["threads"].items() if value["wake_ups"] > 1000}
    realtime, link = summary.get("realtime") or {}, summary.get("link") or {}
    result = {"duration_s": args.duration, "neighbour": args.neighbour, "status": summary["status"],
              "steps": summary["steps_completed"], "error": summary.get("error"), "overruns": realtime.get("overruns"),
              "drive_gap_max_ms": None if link.get("drive_gap_max_s") is None else link["drive_gap_max_s"] * 1e3,
              "steal": realtime.get("steal"), **report}
    print(json.dumps(result, indent=1), flush=True)
    print(record.save("sched-trace-neighbour" if args.neighbour else "sched-trace", result), flush=True)


def tables(result: dict) -> list[record.Table]:
    return [record.Table(f"The last {result['traced_s']} s of a {result['duration_s']:g} s run ({result['status']}, "
                         f"{result['steps']} steps); the real-time threads that woke at 2 kHz:",
                         ["thread", "wake-ups", "wake-up p50 / p99 / p99.9 [µs]", "longest [ms]",
                          "waits > 1 ms, by the task on the CPU", "longest on the CPU [ms] (over 5 ms)",
                          "longest asleep in the kernel, state D [ms]",
                          f"longest on the CPU in the last {LAST_S:g} s [ms]"],
                         [[label, t["wake_ups"], f"{t['wake_p50_us']} / {t['wake_p99_us']} / {t['wake_p999_us']}",
                           t["wake_max_ms"], ", ".join(f"{k} {v}" for k, v in t["waits_over_1ms_by_holder"].items())
                           or "-", _listed(t, "longest_stretches_ms") + (f" ({t['stretches_over_5ms']})"
                                                                          if "stretches_over_5ms" in t else ""),
                           _listed(t, "longest_blocked_in_kernel_ms"), _listed(t, "longest_stretches_in_last_s_ms")]
                          for label, t in result["threads"].items()])]


def _listed(thread: dict, key: str) -> str:
    """The values, "-" for none, "not recorded" in a result from before the bench measured them."""
    if key not in thread:
        return "not recorded"
    return ", ".join(map(str, thread[key])) or "-"


def title(result: dict) -> str:
    return ("What holds the compiled HIL loop's real-time threads up, seen by the kernel's scheduler"
            + (", beside a CPU-bound process" if result.get("neighbour") else "") + " (docs/hil.md)")


def findings(result: dict) -> list[str]:
    steal = {key: "-" if value is None else f"{value:.2f}" for key, value in (result.get("steal") or {}).items()}
    late = ("" if result.get("overruns") is None else
            f" {result['overruns']} steps late, the longest gap between DRIVEs {result['drive_gap_max_ms']:.2f} ms.")
    return [f"The run: {result['error'] or 'completed'}.{late} "
            f"The hypervisor's steal: {steal.get('share_percent', '-')} % "
            f"over the loop, {steal.get('worst_second_percent', '-')} % in its worst second, "
            f"{steal.get('last_second_percent', '-')} % in its last (docs/hil.md, \"The compiled loop\")."]


if __name__ == "__main__":
    main()
