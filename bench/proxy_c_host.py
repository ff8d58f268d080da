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
    print(f"HardwareProxy in the C host against nfal rig-emulator: runs {args.runs}  exit codes "
          f"{dict(collections.Counter(runs.exit_codes))}  measured heights {min(heights, default=0):.3g}.."
          f"{max(heights, default=0):.3g} m  sessions opened {output.count('HELLO: session open')}, ended "
          f"{output.count('STOP: session ended')} (the emulator's log)")
    if runs.first_failure:
        print(f"first failure:\n{runs.first_failure[-3000:]}")


if __name__ == "__main__":
    main()
