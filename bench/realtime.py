"""Real time at full length, on an idle or a busy machine (docs/hil.md, "Real time that holds").

    python bench/realtime.py identify --runs 10 --truths default mass damping [--neighbour]
    python bench/realtime.py hil --duration 600 [--neighbour] [--host-rt-priority 50] [--compiled]
    python bench/realtime.py hil --duration 120 --lockstep   # the host's memory over 240 000 steps, unpaced
    python bench/realtime.py tests --runs 20            # the suite's real-time tests; the neighbour in every other run
    python bench/realtime.py suite --runs 2             # the whole suite, its real-time tests beside the rest

The rig emulator stands for the rig, a separate machine: it runs under SCHED_FIFO (priority 50) where the system
allows it, with its default 100 ms watchdog. The host (``nfal identify``, ``nfal run fig7_hil``) runs at normal
priority, unless ``--host-rt-priority N`` (hil) gives it SCHED_FIFO too (with ``--compiled``, ``nfal run --compiled``:
the compiled loop's thread, docs/hil.md "The compiled loop"). ``--neighbour`` starts a CPU-bound process
at normal priority beside them (``python -c "while True: pass"``). Each command prints one JSON line per run and
writes the whole result, with the machine and the command, to
``bench/results/realtime-<kind>[-compiled][-lockstep][-fifo][-neighbour].json``. ``tests`` and ``suite`` also
record each run's wall time and the CPU time of its whole process tree (user + system, every pytest worker and what
the tests start).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import resource
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import record
from machine import describe

from nfal.realtime import steal_s

HERE = Path(__file__).resolve().parent
#: The emulator's truths for the identification runs: the design model's and two it was not designed for.
TRUTHS = {"default": [], "mass": ["--param", "Plant.mass=0.18"],
          "damping": ["--param", "Plant.excess_damping_height=115e-6", "--param", "Plant.excess_damping_exponent=8"]}
#: The staircase of Figs. 9-10, repeated for a long HIL run [m].
CYCLE = (60e-6, 100e-6, 140e-6, 180e-6, 140e-6, 100e-6)
RT_PRIORITY = "50"
#: How often the HIL run's resident memory is sampled [s].
MEMORY_EVERY_S = 5


@contextlib.contextmanager
def neighbour(enabled: bool) -> Iterator[None]:
    """A CPU-bound process at normal priority, for the duration of the block."""
    process = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if enabled else None
    try:
        yield
    finally:
        if process is not None:
            process.kill()
            process.wait()


@contextlib.contextmanager
def emulator(folder: Path, *options: str) -> Iterator[tuple[str, subprocess.Popen]]:
    """`nfal rig-emulator` under SCHED_FIFO (if allowed), default watchdog: (its port, the process)."""
    priority = ["--rt-priority", RT_PRIORITY] if os.geteuid() == 0 else []
    link = folder / f"rig-{time.monotonic_ns()}.pty"
    log = open(folder / f"{link.stem}.log", "w", encoding="utf-8")  # noqa: SIM115 - closed below
    process = subprocess.Popen([sys.executable, "-m", "nfal", "rig-emulator", "--link", str(link), *priority, *options],
                               stdout=subprocess.PIPE, stderr=log, text=True)
    try:
        port = process.stdout.readline().strip()
        yield port, process
    finally:
        process.terminate()
        rest = process.communicate(timeout=30)[0]
        (folder / f"{link.stem}.events").write_text(rest, encoding="utf-8")
        log.close()


def resident_mb(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/status", encoding="utf-8") as handle:
            return next(int(line.split()[1]) / 1024 for line in handle if line.startswith("VmRSS"))
    except (OSError, StopIteration):
        return None


def run_identify(args, folder: Path) -> list[dict]:
    rows = []
    for truth in args.truths:
        for run in range(args.runs):
            with emulator(folder, *TRUTHS[truth]) as (port, _):
                out = folder / f"{truth}-{run}.json"
                started = time.perf_counter()
                done = subprocess.run([sys.executable, "-m", "nfal", "identify", "--port", port, "--out", str(out),
                                       *(["--mass", "0.18"] if truth == "mass" else [])],
                                      capture_output=True, text=True)
                wall = time.perf_counter() - started
            row = {"truth": truth, "run": run, "exit": done.returncode, "wall_s": round(wall, 1)}
            if done.returncode == 0:
                provenance = json.loads(out.read_text())["provenance"]
                gaps = provenance["realtime"]["drive_gaps"]
                row.update(rig_time_s=round(provenance["rig_time_s"], 1),
                           **{f"drive_gap_{q}_ms": round(gaps[f"{q}_s"] * 1e3, 2) for q in ("p50", "p99", "max")},
                           gc_pause_max_ms=round(provenance["realtime"]["gc_pauses"]["max_s"] * 1e3, 3))
            else:
                row["error"] = done.stderr.strip().splitlines()[-1] if done.stderr.strip() else ""
            print(json.dumps(row), flush=True)
            rows.append(row)
            save(args, rows)
    return rows


def hil_staircase(duration_s: float) -> str:
    """``nfal run --reference``'s staircase for a HIL run of ``duration_s``: CYCLE over and over, 0.6 s holds."""
    levels = [CYCLE[i % len(CYCLE)] for i in range(int(duration_s / 0.6) + 2)]
    return "staircase:" + ",".join(f"{level:g}" for level in levels) + ":0.6:1.0"


def hil_command(port: str, duration_s: float, out: Path, *pacing: str) -> list[str]:
    """``nfal run fig7_hil`` against the rig at ``port`` for ``duration_s`` into ``out``, paced by ``pacing``
    (``--realtime``, ``--compiled``, ...)."""
    return [sys.executable, "-m", "nfal", "run", "fig7_hil", *pacing, "--param", f"proxy.port={port}", "--reference",
            hil_staircase(duration_s), "--stop-time", str(duration_s), "--out", str(out), "--no-plot"]


def run_hil(args, folder: Path) -> list[dict]:
    run_start = provenance()
    out = folder / "hil"
    with emulator(folder, *(["--lockstep"] if args.lockstep else [])) as (port, rig):
        pacing = ["--param", "proxy.lockstep=true"] if args.lockstep else ["--realtime"]
        pacing += ["--compiled"] if args.compiled else []
        if args.host_rt_priority is not None:
            pacing += ["--rt-priority", str(args.host_rt_priority)]
        command = hil_command(port, args.duration, out, *pacing, "--json")
        # to files, not pipes: the summary of a 10-minute run (300 KB of JSON) would fill a pipe nobody reads yet
        # (a run of 2026-11-26 completed, then waited on its own print until killed)
        host_output = open(folder / "host.out", "w+", encoding="utf-8")  # noqa: SIM115 - closed below
        host_errors = open(folder / "host.err", "w+", encoding="utf-8")  # noqa: SIM115 - closed below
        stolen, started = steal_s(), time.perf_counter()
        host = subprocess.Popen(command, stdout=host_output, stderr=host_errors, text=True)
        memory = []  # (MB, results.csv's size) every MEMORY_EVERY_S
        while host.poll() is None:
            with contextlib.suppress(OSError, json.JSONDecodeError):  # from the first step to the summary's end
                if json.loads((out / "summary.json").read_text()).get("status") == "running":
                    memory.append((resident_mb(host.pid), (out / "results.csv").stat().st_size))
            time.sleep(MEMORY_EVERY_S)
        host.wait()
        stolen = None if stolen is None else (steal_s() - stolen, time.perf_counter() - started)
        host_output.close()
        host_errors.close()
        errors = (folder / "host.err").read_text(encoding="utf-8")
    events = (folder / next(folder.glob("*.events")).name).read_text()
    summary = json.loads(out.joinpath("summary.json").read_text())
    realtime, link = summary.get("realtime") or {}, summary.get("link") or {}
    # a sample is the loop's if results.csv grew after it (the loop went on writing), else the read-back's
    running = [later[1] > now[1] for now, later in zip(memory, memory[1:])] + [False]
    loop = [mb for (mb, _), on in zip(memory, running) if mb is not None and on]
    after = [mb for (mb, _), on in zip(memory, running) if mb is not None and not on]
    row = {**run_start, "exit": host.returncode, "host_rt_priority": args.host_rt_priority, "compiled": args.compiled,
           "status": summary["status"],
           "steps": summary.get("steps_completed"),
           "overruns": realtime.get("overruns"),
           "overrun_share_percent": round(100 * realtime.get("overruns", 0) / max(1, realtime.get("steps") or 1), 4),
           "jitter_p99_ms": round(realtime.get("jitter_p99_s", 0) * 1e3, 3),
           "jitter_max_ms": round(realtime.get("jitter_max_s", 0) * 1e3, 2),
           **{f"drive_gap_{q}_ms": round(link.get(f"drive_gap_{q}_s", 0) * 1e3, 2) for q in ("p50", "p99", "max")},
           "gc_pause_max_ms": round((realtime.get("gc_pauses") or {}).get("max_s", 0) * 1e3, 3),
           "step_mean_us": round(realtime.get("step_duration_mean_s", 0) * 1e6),
           "do_step_mean_us": {name: round(fmu["do_step_mean_us"])
                               for name, fmu in (summary.get("timing") or {}).items()},
           "emulator_pacing": next((line for line in events.splitlines() if line.startswith("pacing:")), None),
           "watchdog_trips": events.count("watchdog: no DRIVE"), "missed_sample_stop": "no measurement" in errors,
           "rss_mb_first_last_max": [round(loop[0]), round(loop[-1]), round(max(loop))] if loop else None,
           # every MEMORY_EVERY_S while summary.json says "running", which lasts until the metrics are done
           "rss_every_s": MEMORY_EVERY_S, "rss_mb_samples": [round(mb) for mb in loop],
           "rss_mb_after_loop": [round(mb) for mb in after],
           # the hypervisor's share of the vCPUs over the run: pauses no code here can avoid (docs/hil.md, the floor)
           "steal_percent": None if stolen is None else round(100 * stolen[0] / (stolen[1] * os.cpu_count()), 3),
           # ... and as the loop saw it: its worst second, and the second before it ended (a stop's moment)
           **{f"steal_{key}": None if value is None else round(value, 2)
              for key, value in (realtime.get("steal") or {}).items()},
           "error": summary.get("error")}
    print(json.dumps(row), flush=True)
    save(args, [row])
    return [row]


#: What each kind of test run selects.
SELECTIONS = {"tests": ["-m", "realtime"], "suite": []}


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_tests(args, folder: Path) -> list[dict]:
    """The runs; saved when the loop ends or is interrupted, not after each run: the suite checks that
    docs/benchmarks.md is what bench/results/ gives, and a result file written between two runs would fail the next."""
    rows = []
    try:
        _test_runs(args, rows)
    finally:
        if rows:
            save(args, rows)
    return rows


def _test_runs(args, rows: list[dict]) -> None:
    for run in range(args.runs):
        busy = run % 2 == 1
        with neighbour(busy):
            started, cpu = time.perf_counter(), _children_cpu_s()
            # CI=true: pytest's summary line keeps a failure's message whole (cut to the terminal's width otherwise,
            # which left no room for it); each failure's "E" lines are kept too
            done = subprocess.run([sys.executable, "-m", "pytest", "-q", *SELECTIONS[args.kind], "-p",
                                   "no:cacheprovider"],
                                  cwd=HERE.parent, capture_output=True, text=True, env={**os.environ, "CI": "true"})
            wall, cpu = time.perf_counter() - started, _children_cpu_s() - cpu  # the neighbour is not reaped yet
        last = done.stdout.strip().splitlines()[-1] if done.stdout.strip() else done.stderr[-300:]
        row = {"run": run, "neighbour": busy, "exit": done.returncode, "summary": last, "wall_s": round(wall, 1),
               "cpu_s": round(cpu, 1),
               "failed": [line[:600] for line in done.stdout.splitlines() if line.startswith(("FAILED", "ERROR"))],
               "errors": [line[:300] for line in done.stdout.splitlines() if line.startswith("E ")][:40]}
        print(json.dumps(row), flush=True)
        rows.append(row)


def result_path(args) -> Path:
    """bench/results/realtime-<kind>[-compiled][-lockstep][-fifo][-neighbour].json"""
    name = (f"realtime-{args.kind}" + ("-compiled" if args.kind == "hil" and args.compiled else "")
            + ("-lockstep" if args.kind == "hil" and args.lockstep else "")
            + ("-fifo" if args.kind == "hil" and args.host_rt_priority is not None else "")
            + ("-neighbour" if args.neighbour and args.kind not in SELECTIONS else ""))
    return record.RESULTS / f"{name}.json"


def save(args, rows: list[dict]) -> Path:
    """The machine, the command, every run so far, at result_path(args); each runner saves after each of its runs (an
    interrupted bench keeps what it measured; the test runs save once, run_tests says why). A long HIL run is one run
    a command: its file keeps the runs before it (each with its date and commit), so that a run on a machine whose
    hypervisor took more than usual stands beside the others, not instead of them."""
    path = result_path(args)
    if args.kind == "hil":
        rows = earlier_runs(path) + rows
    return record.save(path.stem, {"runs": rows, "completed": sum(1 for r in rows if r.get("exit") == 0),
                                   "of": len(rows)})


def earlier_runs(path: Path) -> list[dict]:
    """The runs a result file holds, each dated (a run written before runs were dated takes the file's date)."""
    try:
        result = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return []
    return [{"date": result.get("date"), **run} for run in result.get("runs", [])]


def provenance() -> dict:
    """When a run started and at which commit of nfal."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=HERE, capture_output=True, text=True)
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=HERE, capture_output=True,
                           text=True).stdout.strip()
    return {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "commit": (commit.stdout.strip() or None) and commit.stdout.strip() + ("+" if dirty else "")}


def title(result: dict) -> str:
    kind = result["bench"].removeprefix("realtime-")
    if kind == "hil-lockstep":
        return "A long `nfal run fig7_hil` against the emulator in lockstep: the host's memory"
    if kind.startswith("hil"):
        priority = next((f" --rt-priority {run['host_rt_priority']}" for run in result["runs"]
                         if run.get("host_rt_priority") is not None), "")
        engine = " --compiled" if kind.startswith("hil-compiled") else " --realtime"
        return (f"Real time: a long `nfal run fig7_hil{engine}{priority}` "
                + ("beside a CPU-bound process" if kind.endswith("-neighbour") else "against the emulator"))
    return {"identify": "Real time: `nfal identify` against the emulator, full length",
            "identify-neighbour": "Real time: `nfal identify` beside a CPU-bound process",
            "tests": "Real time: the suite's real-time tests in a loop",
            "suite": "Real time: the whole suite in a loop, its real-time tests beside the rest"}[kind]


def _ms_range(values: list[float]) -> str:
    return f"{min(values):.1f}-{max(values):.1f}" if values else "-"


def tables(result: dict) -> list[record.Table]:
    runs, kind = result["runs"], result["bench"].removeprefix("realtime-")
    if kind.startswith("identify"):
        rows = []
        for truth in dict.fromkeys(run["truth"] for run in runs):
            mine = [run for run in runs if run["truth"] == truth]
            done = [run for run in mine if run["exit"] == 0]
            p99 = sorted(run["drive_gap_p99_ms"] for run in done)
            rows.append([truth, f"{len(done)} of {len(mine)}",
                         f"{p99[len(p99) // 2]:.2f}, {p99[-1]:.2f}" if p99 else "-",
                         _ms_range([run["drive_gap_max_ms"] for run in done]),
                         f"{max(run['gc_pause_max_ms'] for run in done) * 1e3:.0f}" if done else "-",
                         _ms_range([run["rig_time_s"] for run in done])])
        return [record.Table("Per truth (the runs that completed):",
                             ["truth", "completed", "DRIVE gaps p99 [ms] (median of runs, worst)",
                              "longest DRIVE gap [ms] (range)", "collector's longest pause [µs]", "rig time [s]"],
                             rows)]
    if kind.startswith("hil"):
        return [record.Table("", ["date", "status", "steps", "overruns [%]", "DRIVE gaps p50 / p99 / max [ms]",
                                  "watchdog trips", "stopped on missed samples", "resident memory in the loop, first / "
                                  "last / max [MB]", "hypervisor's steal: run / worst second / last second [%]"],
                             [[run.get("date", "-"), run["status"], run["steps"], f"{run['overrun_share_percent']:.3f}",
                               f"{run['drive_gap_p50_ms']} / {run['drive_gap_p99_ms']} / {run['drive_gap_max_ms']}",
                               run["watchdog_trips"], "yes" if run["missed_sample_stop"] else "no",
                               " / ".join(map(str, run["rss_mb_first_last_max"] or ["-"])),
                               " / ".join(str(run.get(key, "-")) for key in ("steal_percent",
                                                                             "steal_worst_second_percent",
                                                                             "steal_last_second_percent"))]
                              for run in runs])]
    return [record.Table("", ["run", "CPU-bound process beside", "result", "wall [s]", "CPU, the run's processes [s]",
                              "failed"],
                         [[run["run"], "yes" if run["neighbour"] else "no", run["summary"], run["wall_s"],
                           run.get("cpu_s", "-"),
                           "; ".join(line.removeprefix("FAILED ").split(" - ")[0] for line in run["failed"]) or "-"]
                          for run in runs])]


def _runs_of(values: list) -> str:
    """``197 (120 samples), 693, 441 (12 samples)``: equal neighbours counted, not repeated."""
    groups = [(value, len(list(same))) for value, same in itertools.groupby(values)]
    return ", ".join(f"{value} ({count} samples)" if count > 1 else str(value) for value, count in groups)


def findings(result: dict) -> list[str]:
    out = [f"{result['completed']} of {result['of']} runs completed (exit status 0)."]
    for run in result["runs"]:
        label = f"Run {run['run']}" if "run" in run else f"The run of {run.get('date', '?')}"
        if run.get("error"):
            out.append(f"{label}{' (' + run['truth'] + ')' if 'truth' in run else ''}: {run['error']}")
        if run.get("rss_mb_samples"):
            out.append(f"{label}: resident memory every {run['rss_every_s']} s while the loop ran [MB]: "
                       + _runs_of(run["rss_mb_samples"]) + ".")
        if run.get("rss_mb_after_loop"):
            out.append(f"{label}: after the loop, while the results were read back for the metrics [MB]: "
                       + _runs_of(run["rss_mb_after_loop"]) + ".")
        for line in run.get("errors", [])[:2]:
            out.append(f"Run {run['run']}: `{line.strip()}`")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("kind", choices=("identify", "hil", *SELECTIONS))
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--truths", nargs="+", default=list(TRUTHS), choices=list(TRUTHS))
    parser.add_argument("--duration", type=float, default=600.0, help="hil: seconds of the run (default 600)")
    parser.add_argument("--lockstep", action="store_true", help="hil: the rig in lockstep, the host not paced (its "
                        "memory over many steps, whatever the machine's load)")
    parser.add_argument("--host-rt-priority", type=int, metavar="N", help="hil: the host under SCHED_FIFO at N "
                        "(nfal run --rt-priority N); default: normal priority")
    parser.add_argument("--compiled", action="store_true", help="hil: the compiled loop runs the link and the law "
                        "(nfal run --compiled)")
    parser.add_argument("--neighbour", action="store_true", help="a CPU-bound process beside (tests, suite: "
                        "in every other run, whatever this says)")
    args = parser.parse_args()
    folder = HERE.parent / "runs" / time.strftime(f"realtime-{args.kind}-%Y%m%d-%H%M%S")  # runs/ is ignored
    folder.mkdir(parents=True)
    print(describe(), flush=True)
    runner = {"identify": run_identify, "hil": run_hil, "tests": run_tests, "suite": run_tests}[args.kind]
    with neighbour(args.neighbour and args.kind not in SELECTIONS):
        rows = runner(args, folder)  # each saves its rows as it goes
    print(f"{sum(1 for r in rows if r.get('exit') == 0)} of {len(rows)} completed; {result_path(args)}", flush=True)


if __name__ == "__main__":
    main()
