"""The HardwareProxy FMU in a non-Python host against `nfal rig-emulator`: exit codes of N sessions.

    python bench/proxy_c_host.py [--runs N] [--watchdog SECONDS]

Builds the HardwareProxy (FMI 2.0), starts the emulator on a pty (default truth), and runs the C host
(``fmus/hosts/fmi2_host.c``) N times one after the other with ``port`` set to the pty: instantiate,
initialise (HELLO, first sample), 20 steps of 0.5 ms, terminate (STOP), free, dlclose, exit. Prints the
exit codes, the measured heights read at the end, and how many sessions the emulator reported.
"""

from __future__ import annotations

import argparse
import collections
import subprocess
import sys
import tempfile
from pathlib import Path

import record

from nfal.fmus.build import build_fmus
from nfal.apps.host_check import compile_c_host, run_in_c_host


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=30, help="C-host processes, one after the other (default 30)")
    parser.add_argument("--watchdog", default="0.2", help="the emulator's watchdog [s] (default 0.2: this VM "
                        "stalls a process for more than the rig's 20 ms now and then)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="nfal_proxy_c_host_") as temp:
        folder = Path(temp)
        fmu = build_fmus(folder / "fmus", ["HardwareProxy"])["HardwareProxy"]
        host = compile_c_host(folder)
        emulator = subprocess.Popen([sys.executable, "-m", "nfal", "rig-emulator", "--watchdog", args.watchdog],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            port = emulator.stdout.readline().strip()
            runs = run_in_c_host(host, fmu, folder / "c", runs=args.runs, workers=1, strings={"port": port})
        finally:
            emulator.terminate()
            output, _ = emulator.communicate(timeout=30)
    heights = [outputs["measured_height"] for outputs in runs.outputs]
    result = {"runs": args.runs, "watchdog_s": float(args.watchdog),
              "exit_codes": {str(code): n for code, n in sorted(collections.Counter(runs.exit_codes).items())},
              "heights_m": [min(heights, default=0.0), max(heights, default=0.0)],
              "sessions_opened": output.count("HELLO: session open"),
              "sessions_ended": output.count("STOP: session ended"), "first_failure": runs.first_failure[-3000:]
              if runs.first_failure else None}
    print(record.save("proxy-c-host", result))
    record.show(tables(result), findings(result))


def title(result: dict) -> str:
    return "The HardwareProxy FMU in a C host against the emulator"


def tables(result: dict) -> list[record.Table]:
    low, high = result["heights_m"]
    return [record.Table(f"{result['runs']} C-host processes one after the other (the emulator's watchdog "
                         f"{result['watchdog_s']:g} s):",
                         ["exit codes (code: count)", "measured heights [m]", "sessions opened / ended (rig log)"],
                         [[", ".join(f"{code}: {n}" for code, n in result["exit_codes"].items()),
                           f"{low:.3g} .. {high:.3g}", f"{result['sessions_opened']} / {result['sessions_ended']}"]])]


def findings(result: dict) -> list[str]:
    return [f"First failure: {result['first_failure']}"] if result["first_failure"] else []

if __name__ == "__main__":
    main()
