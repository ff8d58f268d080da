"""Hostile and careless inputs as cases: set-up, the command a new user would type, and how its outcome is judged.

Shared by tests/test_hostile_inputs.py (one case per class of issue 18, in the suite) and
tests/hostile_census.py (every case, by hand, counted in docs/hostile_inputs.md). Each case runs as a new
user would: the real ``nfal`` command line in a fresh folder (``python -m nfal``, its own process, a
timeout), or an FMU through fmpy in its own process (so a crash is seen as one). An outcome is one of

- ``clear error``: refused with exit code 2 and a one-line ``nfal COMMAND: error: ...`` (or, for an FMU,
  an fmi2Error with its logged reason);
- ``handled``: accepted, and right to be (each such case says why), or handled as documented (a signal
  ends the run "interrupted" with every row kept);
- ``traceback``: a Python traceback, or ``internal error`` (the CLI's catch-all for a bug);
- ``crash or hang``: killed by a signal, or still running at the case's timeout;
- ``silently wrong``: accepted although it should not be, a wrong result, or a file that existed before
  the case changed or gone (lost data);
- ``refused valid``: a valid input refused (so that the census cannot pass by refusing everything).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

CLEAR, HANDLED, TRACEBACK, CRASH, WRONG, REFUSED = ("clear error", "handled", "traceback", "crash or hang",
                                                  "silently wrong", "refused valid")
OUTCOMES = (CLEAR, HANDLED, TRACEBACK, CRASH, WRONG, REFUSED)
ERROR_LINE = re.compile(r"^(nfal( [\w-]+)*|fmu): error: \S", re.MULTILINE)


@dataclasses.dataclass
class Case:
    """One hostile input: ``argv`` for ``python -m nfal`` (``{build}``, ``{dir}``, ``{port}`` filled in) or an
    fmpy ``fmu`` case; ``expect`` "error" (must be refused) or "ok" (must be accepted, ``why`` says why)."""

    id: str
    area: str
    argv: list[str] | None = None
    fmu: dict | None = None
    expect: str = "error"
    why: str = ""
    setup: Callable[[Path, Path], None] | None = None
    protect: tuple[str, ...] = ()
    during: Callable[[subprocess.Popen, Path], None] | None = None
    check: Callable[[Path, subprocess.CompletedProcess], str | None] | None = None
    timeout: float = 60.0
    fsize_limit: int | None = None
    exit_code: int = 0  # of an accepted case (a run ended by a signal: 128 + its number)
    needs_permissions: bool = False  # a read-only folder: meaningless as root (who may write anywhere)


@dataclasses.dataclass
class Outcome:
    case: str
    area: str
    outcome: str
    detail: str
    seconds: float


# ---------------------------------------------------------------- running and classifying


def _snapshot(folder: Path, names: tuple[str, ...]) -> dict:
    state = {}
    for name in names:
        path = folder / name
        if path.is_symlink() or path.is_file():
            state[name] = hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "link"
        elif path.is_dir():
            state[name] = sorted(p.name for p in path.iterdir())
        else:
            state[name] = None
    return state


#: Address space a case may take: far above any valid run (about 2 GiB), below what would starve the machine.
MAX_CASE_MEMORY = 8 << 30


def _limit(fsize: int | None) -> None:
    """In the case's process before it runs: a session of its own, MAX_CASE_MEMORY, and ``fsize`` if given."""
    import resource

    os.setsid()
    resource.setrlimit(resource.RLIMIT_AS, (MAX_CASE_MEMORY, MAX_CASE_MEMORY))
    if fsize is not None:  # a full disk: writes past fsize fail with EFBIG (SIGXFSZ ignored)
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))


def command_for(case: Case, folder: Path, build: Path, context: dict) -> list[str]:
    if case.fmu is not None:
        spec = dict(case.fmu, fmu=str(build / f"{case.fmu['fmu']}.fmu"))
        return [sys.executable, "-c", FMU_SCRIPT, json.dumps(spec)]
    fill = {"build": str(build), "dir": str(folder), **context}
    return [sys.executable, "-m", "nfal", *(arg.format(**fill) for arg in case.argv)]


def _prepare(case: Case, root: Path, build: Path) -> tuple[Path, dict, dict]:
    folder = root / case.id
    folder.mkdir(parents=True)
    context = case.setup(folder, build) if case.setup is not None else None
    context = context if isinstance(context, dict) else {}
    return folder, context, _snapshot(folder, case.protect)


def _judge(case: Case, done: subprocess.CompletedProcess, folder: Path, before: dict, seconds: float) -> Outcome:
    outcome, detail = classify(case, done, before, _snapshot(folder, case.protect), folder)
    return Outcome(case.id, case.area, outcome, detail, round(seconds, 2))


def run_case(case: Case, root: Path, build: Path, popen: Callable[..., subprocess.Popen] = subprocess.Popen) -> Outcome:
    """Run ``case`` in its own process in a new folder under ``root`` (the FMUs and archives in ``build``), started
    by ``popen`` (Popen's arguments; the suite forks ``python -m nfal`` from a warm process:
    tests/helpers/warm_nfal.py)."""
    folder, context, before = _prepare(case, root, build)
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    start = time.perf_counter()
    process = popen(command_for(case, folder, build, context), cwd=folder, env=env, text=True, stdout=subprocess.PIPE,
                    stderr=subprocess.PIPE, preexec_fn=functools.partial(_limit, case.fsize_limit))
    try:
        if case.during is not None:
            case.during(process, folder)
        stdout, stderr = process.communicate(timeout=case.timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.communicate()
        return Outcome(case.id, case.area, CRASH, f"still running after {case.timeout:g} s", case.timeout)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        for closer in context.get("_close", ()):
            closer()
    done = subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)
    return _judge(case, done, folder, before, time.perf_counter() - start)


def run_case_in_process(case: Case, root: Path, build: Path) -> Outcome:
    """``case`` through :func:`nfal.cli.main` in this process: for a command refused before it loads an FMU or
    starts anything (faster; a crash here would end the caller)."""
    import contextlib

    from nfal.cli import main

    if case.argv is None or case.during is not None or case.fsize_limit is not None:
        raise ValueError(f"{case.id} runs in its own process only")
    folder, context, before = _prepare(case, root, build)
    argv = command_for(case, folder, build, context)[3:]  # after "python -m nfal"
    stdout, stderr, cwd = io.StringIO(), io.StringIO(), os.getcwd()
    start = time.perf_counter()
    try:
        os.chdir(folder)
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse's usage errors
                code = exc.code if isinstance(exc.code, int) else 2
    finally:
        os.chdir(cwd)
    done = subprocess.CompletedProcess(argv, code, stdout.getvalue(), stderr.getvalue())
    return _judge(case, done, folder, before, time.perf_counter() - start)


def classify(case: Case, done: subprocess.CompletedProcess, before: dict, after: dict, folder: Path) -> tuple[str, str]:
    """The outcome of a finished case and a one-line reason."""
    text = done.stderr + done.stdout
    if done.returncode < 0:
        return CRASH, f"killed by {signal.Signals(-done.returncode).name}: {_last_line(done.stderr)}"
    if "Traceback (most recent call last)" in done.stderr or "internal error:" in done.stderr:
        line = [row for row in done.stderr.splitlines() if row.strip()][-1]
        return TRACEBACK, line[:200]
    lost = [name for name in case.protect if before[name] != after[name]]
    if lost:
        return WRONG, f"changed or removed: {', '.join(lost)}"
    if case.check is not None:
        problem = case.check(folder, done)
        if problem:
            return WRONG, problem
    message = ERROR_LINE.search(text)
    if case.expect == "error":
        if done.returncode == 0:
            return WRONG, "accepted (exit code 0): " + _last_line(done.stdout)
        if case.fmu is not None and done.returncode == 2:  # fmi2Error: the FMU must have logged why
            logged = [row for row in done.stdout.splitlines() if row.startswith("[ERROR]")]
            return (CLEAR, logged[0][:200]) if logged else (WRONG, "fmi2Error with no logged reason")
        if done.returncode == 2 and message:
            return CLEAR, text[message.start():].splitlines()[0][:200]
        return WRONG, f"exit code {done.returncode} without one error line: {_last_line(done.stderr)}"
    if done.returncode != case.exit_code:
        return REFUSED, f"exit code {done.returncode}: {_last_line(done.stderr)}"
    return HANDLED, case.why or _last_line(done.stdout)


def _last_line(text: str) -> str:
    rows = [row for row in text.splitlines() if row.strip()]
    return rows[-1][:200] if rows else "(nothing)"


# ---------------------------------------------------------------- the FMU runner (its own process)

FMU_SCRIPT = r'''
import json, sys
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
spec = json.loads(sys.argv[1])
md = read_model_description(spec["fmu"])
variables = {v.name: v for v in md.modelVariables}
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(spec["fmu"]), modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName="census")
fmu.instantiate(loggingOn=True)  # fmpy's default logger prints the FMU's messages
setters = {"Real": fmu.setReal, "Integer": fmu.setInteger, "Boolean": fmu.setBoolean, "String": fmu.setString}
phase = "set-up"
try:
    for name, value in spec.get("parameters", {}).items():
        setters[variables[name].type]([variables[name].valueReference], [value])
    fmu.setupExperiment(startTime=0.0)
    phase = "initialisation"
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    for name, value in spec.get("inputs", {}).items():
        setters[variables[name].type]([variables[name].valueReference], [value])
    phase = "doStep"
    step = spec.get("step", 5e-4)
    for k in range(spec.get("steps", 10)):
        fmu.doStep(currentCommunicationPoint=k * step, communicationStepSize=step)
    outputs = {v.name: fmu.getReal([v.valueReference])[0] for v in md.modelVariables
               if v.causality == "output" and v.type == "Real"}
except FMICallException as exc:
    print(f"fmu: error: {phase}: {exc}", file=sys.stderr)
    fmu.freeInstance()
    sys.exit(2)
fmu.terminate()
fmu.fmi2FreeInstance(fmu.component)
if spec.get("free_twice"):  # the instance again (fmpy's freeInstance also unloads the library: not that)
    fmu.fmi2FreeInstance(fmu.component)
fmu.freeLibrary()
print(json.dumps(outputs))
'''


def fmu_outputs_plausible(folder: Path, done: subprocess.CompletedProcess) -> str | None:
    """An FMU run that returned OK must give finite outputs and a height within the film's reach."""
    if done.returncode != 0:
        return None
    try:
        outputs = json.loads(done.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return f"no outputs: {_last_line(done.stdout)}"
    bad = {k: v for k, v in outputs.items() if not isinstance(v, float) or v != v or abs(v) == float("inf")}
    if bad:
        return f"non-finite outputs {bad}"
    for name in ("height", "true_height", "measured_height"):
        if name in outputs and abs(outputs[name]) > 5e-3:
            return f"{name} = {outputs[name]:g} m"
    return None


# ---------------------------------------------------------------- set-ups


def files(**contents: str | bytes):
    """A set-up writing these files (names with '__' for '/', '_DOT_' for '.') into the case folder."""
    def setup(folder: Path, build: Path) -> None:
        for name, content in contents.items():
            path = folder / name.replace("__", "/").replace("_DOT_", ".")
            path.parent.mkdir(parents=True, exist_ok=True)
            (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    return setup


def write(name: str, content: str | bytes):
    def setup(folder: Path, build: Path) -> None:
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    return setup


def chain(*setups):
    def setup(folder: Path, build: Path) -> dict:
        context: dict = {}
        for one in setups:
            more = one(folder, build)
            context.update(more if isinstance(more, dict) else {})
        return context
    return setup


def unpacked_fig7(edit: Callable[[str], str] | None = None, name: str = "fig7"):
    """The fig7_slow archive unpacked into folder/name, its SSD passed through ``edit``."""
    def setup(folder: Path, build: Path) -> None:
        target = folder / name
        with zipfile.ZipFile(build / "fig7_slow.ssp") as archive:
            archive.extractall(target)
        if edit is not None:
            ssd = target / "SystemStructure.ssd"
            ssd.write_text(edit(ssd.read_text()))
    return setup


def archive_with(entries: dict[str, bytes | str], compression=zipfile.ZIP_DEFLATED, name: str = "x.ssp"):
    """fig7_slow.ssp with ``entries`` added (or replaced)."""
    def setup(folder: Path, build: Path) -> None:
        with zipfile.ZipFile(build / "fig7_slow.ssp") as source, \
                zipfile.ZipFile(folder / name, "w", compression) as target:
            for item in source.infolist():
                if item.filename not in entries:
                    target.writestr(item, source.read(item.filename))
            for entry, data in entries.items():
                target.writestr(entry, data)
    return setup


def previous_run(folder: Path, build: Path) -> None:
    out = folder / "out"
    out.mkdir()
    (out / "results.csv").write_text("time_s,Plant.height_m\n0,6e-05\n")
    (out / "summary.json").write_text('{"status": "ok", "mine": true}\n')
    (out / "response.png").write_bytes(b"\x89PNG my plot")
    (out / "notes.txt").write_text("my notes\n")


def readonly_folder(folder: Path, build: Path) -> None:
    (folder / "ro").mkdir()
    (folder / "ro" / "keep.txt").write_text("mine\n")
    os.chmod(folder / "ro", 0o555)


def garbage_server(payload: Callable[[int], bytes], close_at_once: bool = False):
    """A TCP 'rig' on localhost that answers a connection with ``payload(i)`` chunks (or closes at once)."""
    def setup(folder: Path, build: Path) -> dict:
        server = socket.create_server(("127.0.0.1", 0))
        server.settimeout(0.2)
        stop = threading.Event()

        def serve():
            while not stop.is_set():
                try:
                    conn, _ = server.accept()
                except OSError:
                    continue
                with conn:
                    if close_at_once:
                        continue
                    conn.settimeout(0.05)
                    i = 0
                    while not stop.is_set():
                        try:
                            conn.sendall(payload(i))
                            conn.recv(4096)
                        except socket.timeout:
                            pass
                        except OSError:
                            break
                        i += 1
                        time.sleep(0.002)

        thread = threading.Thread(target=serve, daemon=True)
        thread.start()

        def close():
            stop.set()
            thread.join(2)
            server.close()
        return {"port": f"socket://127.0.0.1:{server.getsockname()[1]}", "_close": (close,)}
    return setup


# ---------------------------------------------------------------- during a run


def wait_for(condition: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    return False


def _rows(path: Path) -> int:
    try:
        with open(path, "rb") as stream:
            return sum(1 for _ in stream) - 1
    except OSError:
        return 0


def signal_when_rows(number: int, rows: int = 200):
    """Send ``number`` once results.csv (in out/) holds ``rows`` rows."""
    def during(process: subprocess.Popen, folder: Path) -> None:
        if wait_for(lambda: _rows(folder / "out" / "results.csv") >= rows or process.poll() is not None, 60):
            if process.poll() is None:
                os.kill(process.pid, number)
    return during


def interrupted_with_rows(folder: Path, done: subprocess.CompletedProcess) -> str | None:
    summary = json.loads((folder / "out" / "summary.json").read_text())
    rows = _rows(folder / "out" / "results.csv")
    if summary.get("status") != "interrupted" or summary.get("steps_completed") != rows - 1 or rows < 200:
        return f"summary {summary.get('status')!r} with {summary.get('steps_completed')} steps, {rows} rows"
    return None


def emulator_fed_garbage(chunks: list[bytes]):
    """Write ``chunks`` into the rig emulator's pty (its first output line) once it is up."""
    def during(process: subprocess.Popen, folder: Path) -> None:
        line = process.stdout.readline().strip()
        if not line:
            return
        fd = os.open(line, os.O_RDWR | os.O_NOCTTY)
        try:
            for chunk in chunks:
                os.write(fd, chunk)
                time.sleep(0.01)
        finally:
            os.close(fd)
    return during


def summary_failed_with_reason(folder: Path, done: subprocess.CompletedProcess) -> str | None:
    path = folder / "out" / "summary.json"
    if not path.exists():
        return None
    try:
        summary = json.loads(path.read_text())
    except ValueError:
        return "summary.json is not JSON"
    if summary.get("status") == "running":
        return "summary.json left at 'running'"
    return None


def disk_full_reported(folder: Path, done: subprocess.CompletedProcess) -> str | None:
    """A run the disk stopped: failed with a reason that names the file, and rows_written what is on disk."""
    failed = summary_failed_with_reason(folder, done)
    if failed is not None:
        return failed
    summary = json.loads((folder / "out" / "summary.json").read_text())
    rows = (folder / "out" / "results.csv").read_bytes().count(b"\n") - 1
    if summary.get("rows_written") != rows:
        return f"summary.json says {summary.get('rows_written')} rows written, results.csv holds {rows}"
    if "results.csv" not in str(summary.get("error")):
        return f"the error does not name the file: {summary.get('error')!r}"
    return None


def error_names(text: str):
    """The refusal says ``text`` (it is refused for the reason the case is about, not a later one)."""
    def check(folder: Path, done: subprocess.CompletedProcess) -> str | None:
        return None if done.returncode != 2 or text in done.stderr else f"the error does not name {text!r}"
    return check


def error_leads_with(prefix: str):
    """The error starts with ``prefix`` (the cause, not FMI plumbing) and is one line: the command line's ends its
    output (no array or traceback after it); an FMU's (``prefix`` "[ERROR] ...") is its first logged error."""
    def check(folder: Path, done: subprocess.CompletedProcess) -> str | None:
        rows = [row for row in done.stderr.splitlines() if row.strip()][-1:]
        if prefix.startswith("[ERROR]"):
            rows = [row for row in done.stdout.splitlines() if row.startswith("[ERROR]")][:1]
        if not rows or not rows[0].startswith(prefix):
            return f"the error is not one line leading with {prefix!r}: {rows[0][:200] if rows else '(none)'}"
        return None
    return check


def calibration_file(**changes) -> str:
    """A calibration file as nfal identify writes one (eq. 17's K, a damping table, the paper's rig), with ``changes``
    (a value of None removes the entry)."""
    document = {"version": 1, "kind": "polynomial", "name": "identified", "sigma_range": [10.0, 500.0],
                "coefficients": [1.2348, 2.2928e-2, -1.301e-4, 2.9826e-7, -2.4985e-10],
                "damping": {"heights_m": [50e-6, 100e-6, 150e-6, 200e-6], "factors": [1.0, 1.3, 2.1, 4.0]},
                "rig": {"mass": 0.1347, "radius": 0.05, "frequency": 28.5e3, "viscosity": 1.81e-5,
                        "ambient_pressure": 101325.0, "gravity": 9.81}}
    document.update(changes)
    return json.dumps({key: value for key, value in document.items() if value is not None})


#: A damping table in um, and a short identification's K (80-98 um).
UM_DAMPING = {"heights_m": [49.2, 80.0, 120.0, 160.0, 200.0], "factors": [1.0, 1.2, 1.6, 2.5, 4.0]}
SHORT_K = {"sigma_range": [100.0, 150.0], "damping": None}


def file_absent(name: str):
    def check(folder: Path, done: subprocess.CompletedProcess) -> str | None:
        return f"{name} was written" if (folder / name).exists() else None
    return check


# ---------------------------------------------------------------- the cases

RUN = ["run", "--build-dir", "{build}", "--stop-time", "0.02", "--out", "out"]
NAN_WORDS = ("nan", "inf", "-inf", "1e400", "abc", "")


def cli_cases() -> list[Case]:
    cases = [
        Case("no-command", "cli", [], ),
        Case("unknown-command", "cli", ["frobnicate"]),
        Case("run-unknown-structure", "cli-run", ["run", "no_such_loop", "--out", "out"]),
        Case("run-negative-step", "cli-run", RUN + ["--step=-5e-4"]),
        Case("run-zero-step", "cli-run", RUN + ["--step", "0"]),
        Case("run-stop-before-start", "cli-run", RUN + ["--start-time", "1"]),
        Case("run-stop-1e9", "cli-run", RUN[:-4] + ["--stop-time", "1e9", "--out", "out"]),
        Case("run-step-1e-9", "cli-run", RUN + ["--step", "1e-9"]),
        Case("run-step-not-multiple", "cli-run", RUN + ["--step", "3e-4"]),
        Case("run-max-steps-negative", "cli-run", RUN + ["--max-steps", "-1"]),
        Case("run-max-steps-0", "cli-run", RUN + ["--max-steps", "0"]),
        Case("run-bad-algorithm", "cli-run", RUN + ["--algorithm", "gauss"]),
        Case("run-param-no-equals", "cli-run", RUN + ["--param", "Plant.mass"]),
        Case("run-param-no-element", "cli-run", RUN + ["--param", "mass=0.1"]),
        Case("run-param-unknown-element", "cli-run", RUN + ["--param", "Plnat.mass=0.1"]),
        Case("run-param-unknown-variable", "cli-run", RUN + ["--param", "Plant.mas=0.1"]),
        Case("run-param-negative-mass", "cli-run", RUN + ["--param", "Plant.mass=-1"]),
        Case("run-param-zero-mass", "cli-run", RUN + ["--param", "Plant.mass=0"]),
        Case("run-param-mass-grams", "cli-run", RUN + ["--param", "Plant.mass=134.7"]),
        Case("run-param-mass-nan", "cli-run", RUN + ["--param", "Plant.mass=nan"]),
        Case("run-param-mass-inf", "cli-run", RUN + ["--param", "Plant.mass=inf"]),
        Case("run-param-mass-word", "cli-run", RUN + ["--param", "Plant.mass=heavy"]),
        Case("run-param-radius-mm", "cli-run", RUN + ["--param", "Plant.radius=50"]),
        Case("run-param-initial-height-um", "cli-run", RUN + ["--param", "Plant.initial_height=60"]),
        Case("run-param-seed-2pow32", "cli-run", RUN + ["--param", "SensorChain.seed=4294967296"]),
        Case("run-param-seed-negative-2pow31-1", "cli-run", RUN + ["--param", "SensorChain.seed=-2147483649"]),
        Case("run-param-seed-fraction", "cli-run", RUN + ["--param", "SensorChain.seed=1.5"]),
        Case("run-param-bool-word", "cli-run", RUN + ["--param", "ResonanceTracker.pll_enabled=maybe"]),
        Case("run-param-bool-number", "cli-run", RUN + ["--param", "ResonanceTracker.pll_enabled=2"]),
        Case("run-param-output", "cli-run", RUN + ["--param", "Plant.height=1"]),
        Case("run-param-design-bogus", "cli-run", RUN + ["--param", "Controller.design=bogus"]),
        Case("run-param-calibration-missing-file", "cli-run", RUN + ["--param", "Controller.calibration=nothing.json"]),
        Case("run-param-calibration-binary", "cli-run", RUN + ["--param", "Controller.calibration=k.json"],
             setup=write("k.json", os.urandom(512))),
        Case("run-param-calibration-k-zero", "cli-run", RUN + ["--param", "Plant.calibration=k.json"],
             setup=write("k.json", json.dumps({"version": 1, "kind": "table", "name": "zero",
                                               "sigma": [1, 10, 100, 1000], "K": [0, 0, 0, 0]}))),
        Case("run-param-calibration-k-negative", "cli-run", RUN + ["--param", "Controller.calibration=k.json"],
             setup=write("k.json", json.dumps({"version": 1, "kind": "table", "name": "neg",
                                               "sigma": [1, 10, 100, 1000], "K": [-1, -1, -1, -1]}))),
        Case("run-param-calibration-list", "cli-run", RUN + ["--param", "Controller.calibration=k.json"],
             setup=write("k.json", "[1, 2, 3]")),
        Case("run-param-calibration-dev-zero", "cli-run", RUN + ["--param", "Controller.calibration=/dev/zero"],
             timeout=60),
        Case("run-param-calibration-damping-um", "calibration", RUN + ["--param", "Controller.calibration=k.json"],
             setup=write("k.json", calibration_file(damping=UM_DAMPING)),
             check=error_leads_with("nfal run: error: Controller: calibration k.json: damping.heights_m = [49.2")),
        Case("run-param-calibration-short", "calibration", RUN + ["--param", "Controller.calibration=k.json"],
             setup=write("k.json", calibration_file(**SHORT_K)),
             check=error_leads_with("nfal run: error: Controller: design heights = 50.0–200.0 µm is invalid")),
        Case("run-param-mass-negative-cause-first", "cli-run", RUN + ["--param", "Controller.mass=-1"],
             check=error_leads_with("nfal run: error: Controller: mass = -1.0 is invalid: must be")),
        Case("run-param-sensor-noise-negative", "cli-run", RUN + ["--param", "SensorChain.noise_peak=-1e-6"]),
        Case("run-param-tracker-q-zero", "cli-run", RUN + ["--param", "ResonanceTracker.quality_factor=0"]),
        Case("run-param-max-excitation-1m", "cli-run", RUN + ["--param", "Controller.max_excitation=1"]),
        Case("run-param-reference-range-inverted", "cli-run",
             RUN + ["--param", "Controller.reference_min=200e-6", "--param", "Controller.reference_max=50e-6"]),
        Case("run-param-sample-rate-zero", "cli-run", RUN + ["--param", "Controller.sample_rate=0"]),
        Case("run-param-sample-rate-not-dividing", "cli-run", RUN + ["--param", "Controller.sample_rate=3000"]),
        Case("run-input-unknown", "cli-run", RUN + ["--input", "Plant.nothing=constant:1"]),
        Case("run-input-bad-signal", "cli-run", RUN + ["--input", "ResonanceTracker.resonance_shift=sine:1"]),
        Case("run-input-nan", "cli-run", RUN + ["--input", "ResonanceTracker.resonance_shift=constant:nan"]),
        Case("run-input-huge-shift", "cli-run", RUN + ["--input", "ResonanceTracker.resonance_shift=constant:1e300"]),
        Case("run-input-parameter", "cli-run", RUN + ["--input", "Plant.mass=constant:0.1"]),
        Case("run-reference-missing-csv", "cli-run", RUN + ["--reference", "ref.csv"]),
        Case("run-reference-binary-csv", "cli-run", RUN + ["--reference", "ref.csv"],
             setup=write("ref.csv", os.urandom(300))),
        Case("run-reference-mm", "cli-run", RUN + ["--reference", "ref.csv"],
             setup=write("ref.csv", "time_s,reference_m\n0,0.1\n")),
        Case("run-reference-negative", "cli-run", RUN + ["--reference", "ref.csv"],
             setup=write("ref.csv", "time_s,reference_m\n0,-1e-4\n")),
        Case("run-reference-nan", "cli-run", RUN + ["--reference", "ref.csv"], setup=write("ref.csv", "0,nan\n")),
        Case("run-reference-staircase-mm", "cli-run", RUN + ["--reference", "staircase:100,140"]),
        Case("run-reference-staircase-negative-hold", "cli-run", RUN + ["--reference", "staircase:1e-4,1.4e-4:-1"]),
        Case("run-reference-staircase-junk", "cli-run", RUN + ["--reference", "staircase:a,b"]),
        Case("run-reference-input-unknown", "cli-run", RUN + ["--reference-input", "Nothing.x"]),
        # the structure's own experiment (the ReferenceGenerator), edited from the command line
        Case("run-generator-levels-mm", "cli-run", RUN + ["--param", "ReferenceGenerator.levels=100 140"]),
        Case("run-generator-levels-junk", "cli-run", RUN + ["--param", "ReferenceGenerator.levels=60um,100um"]),
        Case("run-generator-one-level", "cli-run", RUN + ["--param", "ReferenceGenerator.levels=60e-6"]),
        Case("run-generator-hold-negative", "cli-run", RUN + ["--param", "ReferenceGenerator.hold=-0.6"]),
        Case("run-generator-table-nan", "cli-run", RUN + ["--param", "ReferenceGenerator.table=0,60e-6;0.01,nan"]),
        Case("run-generator-table-outside", "cli-run",
             RUN + ["--param", "ReferenceGenerator.table=../../../etc/x.csv"]),
        Case("run-rt-priority-without-realtime", "cli-run", RUN + ["--rt-priority", "50"]),
        Case("run-rt-priority-200", "cli-run", RUN + ["--realtime", "--rt-priority", "200"]),
        Case("run-hil-without-port", "cli-run", ["run", "fig7_hil", "--build-dir", "{build}", "--out", "out"]),
        Case("run-hil-missing-port", "cli-run", ["run", "fig7_hil", "--build-dir", "{build}", "--stop-time", "0.1",
                                                 "--out", "out", "--param", "proxy.port=/nonexistent/tty"], timeout=60),
        Case("run-readonly-build-dir", "cli-run",
             ["run", "--build-dir", "ro/build", "--stop-time", "0.02", "--out", "out"],
             needs_permissions=True, setup=readonly_folder),
        Case("run-build-dir-is-file", "cli-run", ["run", "--build-dir", "f", "--stop-time", "0.02", "--out", "out"],
             setup=write("f", "mine\n"), protect=("f",)),
        Case("run-stop-time-not-whole-steps", "cli-run", RUN[:-4] + ["--stop-time", "0.0203", "--out", "out"],
             expect="ok", why="ends at the last whole step (0.0200 s) with a warning naming it"),
        Case("run-short-ok", "cli-run", RUN, expect="ok", why="a valid short run"),
    ]
    for word in NAN_WORDS:
        cases.append(Case(f"run-stop-time-{word or 'empty'}", "cli-run",
                          RUN[:-4] + [f"--stop-time={word}", "--out", "out"]))
        cases.append(Case(f"run-start-time-{word or 'empty'}", "cli-run", RUN + [f"--start-time={word}"]))
    # results folders
    cases += [
        Case("run-out-previous-run", "results", RUN, setup=previous_run,
             protect=("out/results.csv", "out/summary.json", "out/response.png", "out/notes.txt")),
        Case("run-out-previous-run-fails-at-start", "results", RUN + ["--param", "Plant.mass=-1"], setup=previous_run,
             protect=("out/results.csv", "out/summary.json", "out/response.png", "out/notes.txt")),
        Case("run-out-overwrite-keeps-other-files", "results", RUN + ["--overwrite"], setup=previous_run,
             protect=("out/notes.txt",), expect="ok", why="--overwrite replaces only the run's three files"),
        Case("run-out-is-a-file", "results", RUN, setup=write("out", "mine\n"), protect=("out",)),
        Case("run-out-readonly", "results", RUN[:-1] + ["ro/out"], needs_permissions=True,
             setup=readonly_folder, protect=("ro/keep.txt",)),
        Case("run-out-readonly-itself", "results", RUN[:-1] + ["ro"], needs_permissions=True,
             setup=readonly_folder, protect=("ro/keep.txt", "ro")),
        Case("run-out-dev-null", "results", RUN[:-1] + ["/dev/null"]),
        Case("run-out-full-disk", "results", ["run", "{build}/fig7_slow.ssp", "--stop-time", "5", "--reference",
                                              "staircase:1e-4,1.4e-4:2", "--out", "out"], fsize_limit=1_000_000,
             check=disk_full_reported),
        Case("run-sigint", "results", RUN[:-4] + ["--stop-time", "20", "--out", "out"], expect="ok",
             why="Ctrl-C: summary 'interrupted', every row kept, exit 130",
             during=signal_when_rows(signal.SIGINT), exit_code=128 + signal.SIGINT,
             check=interrupted_with_rows, timeout=90),
        Case("run-sigterm", "results", RUN[:-4] + ["--stop-time", "20", "--out", "out"], expect="ok",
             why="SIGTERM: summary 'interrupted', every row kept, exit 143",
             during=signal_when_rows(signal.SIGTERM), exit_code=128 + signal.SIGTERM,
             check=interrupted_with_rows, timeout=90),
        Case("run-sighup", "results", RUN[:-4] + ["--stop-time", "20", "--out", "out"], expect="ok",
             why="SIGHUP (terminal closed): summary 'interrupted', every row kept",
             during=signal_when_rows(signal.SIGHUP), exit_code=128 + signal.SIGHUP,
             check=interrupted_with_rows, timeout=90),
        Case("run-plot-extension", "results", ["calibrate", "numerical", "--plot", "k.jpg"]),
        Case("run-plot-missing-folder", "results", ["calibrate", "numerical", "--plot", "no/such/k.png"]),
        Case("calibrate-out-readonly", "results", ["calibrate", "numerical", "--out", "ro/k.json"],
             needs_permissions=True, setup=readonly_folder),
        Case("calibrate-out-is-folder", "results", ["calibrate", "numerical", "--out", "k.json"],
             setup=lambda f, b: (f / "k.json").mkdir()),
        Case("calibrate-out-existing-file", "results", ["calibrate", "numerical", "--out", "k.json"],
             setup=write("k.json", "mine\n"), expect="ok",
             why="a single output file named by the user is theirs to replace (as cp, numpy.save); "
             "a results folder is not"),
    ]
    return cases


def physics_cases() -> list[Case]:
    cal = ["calibrate", "numerical"]
    cases = [Case(f"calibrate-shape-{name}", "cli-calibrate", cal + ["--shape", shape]) for name, shape in [
        ("plate-1000", "plate:1000"), ("plate-neg", "plate:-1"), ("plate-word", "plate:x"), ("bogus", "bogus"),
        ("missing-csv", "scan.csv"), ("dir", "."), ("dev-zero", "/dev/zero")]]
    cases += [
        Case("calibrate-shape-binary-csv", "cli-calibrate", cal + ["--shape", "s.csv"],
             setup=write("s.csv", os.urandom(400))),
        Case("calibrate-shape-zero", "cli-calibrate", cal + ["--shape", "s.csv"],
             setup=write("s.csv", "0,0\n0.3,0\n0.6,0\n1,0\n")),
        Case("calibrate-shape-nan", "cli-calibrate", cal + ["--shape", "s.csv"],
             setup=write("s.csv", "0,1\n0.5,nan\n1,0\n")),
        Case("calibrate-shape-r-beyond-1", "cli-calibrate", cal + ["--shape", "s.csv"],
             setup=write("s.csv", "0,1\n1,0.7\n2,0.5\n4,0\n")),
        Case("calibrate-shape-one-row", "cli-calibrate", cal + ["--shape", "s.csv"], setup=write("s.csv", "0,1\n")),
        Case("calibrate-shape-unsorted", "cli-calibrate", cal + ["--shape", "s.csv"],
             setup=write("s.csv", "1,0\n0,1\n0.5,0.5\n0.5,0.2\n")),
        Case("calibrate-sigma-negative", "cli-calibrate", cal + ["--sigma=-5,10"]),
        Case("calibrate-sigma-zero-count", "cli-calibrate", cal + ["--sigma", "5:500:0"]),
        Case("calibrate-sigma-huge-count", "cli-calibrate", cal + ["--sigma", "5:500:1000000000"], timeout=60),
        Case("calibrate-sigma-nan", "cli-calibrate", cal + ["--sigma", "nan"]),
        Case("calibrate-nodes-0", "cli-calibrate", cal + ["--nodes", "0"]),
        Case("calibrate-nodes-huge", "cli-calibrate", cal + ["--nodes", "2147483647"]),
        Case("calibrate-tm-steps-huge", "cli-calibrate",
             cal + ["--method", "time-marching", "--steps-per-period", "2147483647"]),
        Case("calibrate-tm-delta-2", "cli-calibrate", cal + ["--method", "time-marching", "--delta", "2"]),
        Case("calibrate-tm-delta-negative", "cli-calibrate", cal + ["--method", "time-marching", "--delta", "-0.1"]),
        Case("calibrate-delta-nan", "cli-calibrate", cal + ["--delta", "nan"]),
    ]
    exp = ["calibrate", "experimental", "eq.csv"]
    good = "height_m,excitation_m\n" + "".join(f"{h:.3e},{a:.3e}\n" for h, a in
                                                [(60e-6, 2e-6), (90e-6, 3e-6), (120e-6, 4.2e-6), (150e-6, 5.5e-6),
                                                 (180e-6, 7e-6), (70e-6, 2.3e-6)])
    for name, text in [
        ("binary", os.urandom(500)), ("empty", ""), ("header-only", "height_m,excitation_m\n"),
        ("no-columns", "a,b\n1,2\n3,4\n"), ("duplicate-column", "height_m,height_m,excitation_m\n6e-5,7e-5,2e-6\n"),
        ("mm-heights", good.replace("e-05", "e-02")), ("negative-height", good.replace("6.000e-05", "-6.000e-05")),
        ("nan", good.replace("6.000e-05", "nan")), ("words", "height_m,excitation_m\nx,y\n"),
        ("excitation-above-gap", good.replace("2.000e-06", "2.000e-03")),
        ("one-row", "height_m,excitation_m\n6e-5,2e-6\n"),
    ]:
        cases.append(Case(f"calibrate-experimental-{name}", "csv", exp, setup=write("eq.csv", text)))
    volts = "height_m,voltage_v\n" + "".join(f"{h:.3e},{v}\n" for h, v in [(60e-6, 20), (90e-6, 30), (120e-6, 42),
                                                                             (150e-6, 55), (180e-6, 70), (70e-6, 23)])
    cases += [
        Case("calibrate-experimental-mpv-1e300", "csv", exp + ["--metres-per-volt", "1e300"],
             setup=write("eq.csv", volts)),
        Case("calibrate-experimental-mpv-negative", "csv", exp + ["--metres-per-volt=-1e-7"],
             setup=write("eq.csv", volts)),
        Case("calibrate-experimental-mpv-zero", "csv", exp + ["--metres-per-volt", "0"], setup=write("eq.csv", volts)),
        Case("calibrate-experimental-no-map", "csv", exp, setup=write("eq.csv", volts)),
        Case("calibrate-experimental-voltage-map-binary", "csv", exp + ["--voltage-map", "m.csv"],
             setup=chain(write("eq.csv", volts), write("m.csv", os.urandom(200)))),
        Case("calibrate-experimental-degree-negative", "csv", exp + ["--degree", "-1"], setup=write("eq.csv", good)),
        Case("calibrate-experimental-degree-huge", "csv", exp + ["--degree", "100000"], setup=write("eq.csv", good)),
        Case("calibrate-experimental-magnetic-nan", "csv", exp,
             setup=write("eq.csv", "height_m,excitation_m,magnetic_force_n\n"
                                   "6e-5,2e-6,nan\n9e-5,3e-6,0\n1.2e-4,4.2e-6,0\n")),
        Case("calibrate-experimental-good", "csv", exp, setup=write("eq.csv", good), expect="ok",
             why="six plausible equilibria"),
    ]
    val = ["validate", "table1"]
    cases += [
        Case("validate-case-z", "cli-validate", val + ["--cases", "z"]),
        Case("validate-cases-empty", "cli-validate", val + ["--cases", ""]),
        Case("validate-nodes-1", "cli-validate", val + ["--cases", "a", "--nodes", "1"]),
        Case("validate-nodes-huge", "cli-validate", val + ["--cases", "a", "--nodes", "2147483647"]),
        Case("validate-steps-0", "cli-validate", val + ["--cases", "a", "--steps-per-period", "0"]),
        Case("validate-steps-huge", "cli-validate", val + ["--cases", "a", "--steps-per-period", "99999999999"]),
    ]
    return cases


def control_cases() -> list[Case]:
    cases = [Case(f"design-{name}", "cli-design", ["design", *argv]) for name, argv in [
        ("heights-negative", ["--heights=-1e-4,1e-4"]), ("heights-mm", ["--heights", "50:200:4"]),
        ("heights-huge-count", ["--heights", "5e-5:2e-4:100000000"]), ("cutoff-zero", ["--closed-loop-cutoff", "0"]),
        ("cutoff-negative", ["--closed-loop-cutoff", "-10"]), ("filter-nan", ["--filter-cutoff", "nan"]),
        ("sample-rate-zero", ["--sample-rate", "0"]), ("sample-rate-negative", ["--sample-rate", "-2000"]),
        ("mass-zero", ["--mass", "0"]), ("mass-grams", ["--mass", "134.7"]), ("radius-mm", ["--radius", "50"]),
        ("frequency-negative", ["--frequency", "-28500"]), ("viscosity-zero", ["--viscosity", "0"]),
        ("pressure-negative", ["--ambient-pressure", "-1"]), ("calibration-missing", ["--calibration", "none.json"]),
        ("placement-bogus", ["--placement", "bogus"]), ("discretisation-bogus", ["--discretisation", "bogus"]),
        ("reference-clearance-mm", ["--reference-clearance", "10"])]]
    cases += [Case(f"design-{name}", "cli-design", ["design", *argv],
                   check=error_leads_with(f"nfal design: error: {lead}"))
              for name, argv, lead in [  # unit slips (issue 26): they went on to a 6-line array of heights
                  ("frequency-khz", ["--frequency", "28.5"], "frequency = 28.5 is invalid"),
                  ("pressure-kpa", ["--ambient-pressure", "101.325"], "ambient_pressure = 101.325 is invalid"),
                  ("viscosity-upas", ["--viscosity", "18.1"], "viscosity = 18.1 is invalid")]]
    cases += [
        Case("design-calibration-k-zero", "calibration", ["design", "--calibration", "k.json"],
             setup=write("k.json", json.dumps({"version": 1, "kind": "table", "name": "z", "sigma": [1, 10, 100, 1000],
                                               "K": [0, 0, 0, 0]}))),
        Case("design-calibration-version-99", "calibration", ["design", "--calibration", "k.json"],
             setup=write("k.json", json.dumps({"version": 99, "kind": "table", "name": "z", "sigma": [1, 10],
                                               "K": [1, 2]}))),
        Case("design-calibration-kind-bogus", "calibration", ["design", "--calibration", "k.json"],
             setup=write("k.json", json.dumps({"version": 1, "kind": "bogus"}))),
        Case("design-calibration-sigma-unsorted", "calibration", ["design", "--calibration", "k.json"],
             setup=write("k.json", json.dumps({"version": 1, "kind": "table", "name": "z", "sigma": [100, 10, 1000, 30],
                                               "K": [1, 2, 3, 4]}))),
        Case("design-calibration-nan", "calibration", ["design", "--calibration", "k.json"],
             setup=write("k.json", '{"version": 1, "kind": "table", "name": "z", "sigma": [1, 10, 100, 1000], '
                                   '"K": [1, NaN, 3, 4]}')),
        Case("design-calibration-length-mismatch", "calibration", ["design", "--calibration", "k.json"],
             setup=write("k.json", json.dumps({"version": 1, "kind": "table", "name": "z", "sigma": [1, 10, 100, 1000],
                                               "K": [1, 2, 3]}))),
        Case("design-calibration-poly-empty", "calibration", ["design", "--calibration", "k.json"],
             setup=write("k.json", json.dumps({"version": 1, "kind": "polynomial", "name": "z", "coefficients": []}))),
        Case("design-calibration-deep-json", "calibration", ["design", "--calibration", "k.json"],
             setup=write("k.json", "[" * 100000 + "]" * 100000)),
        *(Case(f"design-calibration-{name}", "calibration", ["design", "--calibration", "k.json"],
               setup=write("k.json", calibration_file(**changes)),
               check=error_leads_with(f"nfal design: error: {lead}"))
          for name, changes, lead in [
              ("damping-um", {"damping": UM_DAMPING}, "calibration k.json: damping.heights_m = [49.2, 80.0"),
              ("version-true", {"version": True}, "calibration k.json: version = true is invalid"),
              ("factor-true", {"damping": {"heights_m": [5e-5, 1e-4], "factors": [1.0, True]}},
               "calibration k.json: damping.factors[1] = true is invalid: must be a finite number"),
              ("coefficient-string", {"coefficients": [1.2348, "0.02"]},
               'calibration k.json: coefficients[1] = "0.02"'),
              ("rig-grams", {"rig": {"mass": 134.7}}, "calibration k.json: rig.mass = 134.7 is invalid"),
              ("rig-khz", {"rig": {"frequency": 28.5}}, "calibration k.json: rig.frequency = 28.5 is invalid"),
              ("entry-misspelt", {"dampin": {}}, "calibration k.json: unknown entries ['dampin']"),
              ("short-identification", SHORT_K,
               "design heights = 50.0–200.0 µm is invalid: must be within 80.0–98.0 µm")]),
        Case("design-calibration-identified", "calibration", ["design", "--calibration", "k.json"],
             setup=write("k.json", calibration_file()), expect="ok",
             why="a calibration file as nfal identify writes it: every field in its range"),
        Case("design-calibration-huge-number", "calibration", ["design", "--calibration", "k.json"],
             setup=write("k.json", '{"version": 1, "kind": "table", "name": "z", "sigma": [1, 10, 100, 1000], '
                                   '"K": [1, 1e999, 3, 4]}')),
    ]
    compare = ["compare", "--controllers"]
    cases += [Case(f"compare-{name}", "cli-compare", argv) for name, argv in [
        ("controllers-bogus", compare + ["bogus"]), ("controllers-empty", compare + [""]),
        ("controllers-negative", ["compare", "--controllers=-80"]), ("controllers-mm", compare + ["gs,80000"]),
        ("levels-mm", ["compare", "--levels", "60,100"]), ("hold-zero", ["compare", "--hold", "0"]),
        ("hold-huge", ["compare", "--hold", "1e9"]), ("noise-negative", ["compare", "--noise-peak", "-1"]),
        ("noise-cutoff-zero", ["compare", "--noise-cutoff", "0"]),
        ("max-excitation-zero", ["compare", "--max-excitation", "0"]),
        ("max-excitation-1m", ["compare", "--max-excitation", "1"]), ("seed-negative", ["compare", "--seed", "-1"]),
        ("seed-2pow64", ["compare", "--seed", str(2 ** 64)])]]
    cases[-1].expect, cases[-1].why = "ok", "numpy seeds from any whole number >= 0 without truncation (SeedSequence)"
    # was a numpy repr of a height
    cases.append(Case("compare-noise-um", "cli-compare", ["compare", "--noise-peak", "2"],
                      check=error_leads_with("nfal compare: error: peak_m = 2.0 is invalid")))
    # an option with no effect in the mode chosen (issue 26): refused, naming it, before anything is built or run
    short = ["compare", "--controllers", "gs", "--levels", "100e-6,120e-6", "--hold", "0.1"]
    rig = ["--port", "/nonexistent/port"]
    cases += [Case(f"compare-{name}", "cli-compare", short + argv, check=error_names(f"{flag} has no effect"))
              for name, flag, argv in [
                  ("runs-dir-without-port", "--runs-dir", ["--runs-dir", "runs"]),
                  ("build-dir-without-port", "--build-dir", ["--build-dir", "b"]),
                  ("param-without-port", "--param", ["--param", "proxy.max_missed_samples=100"]),
                  ("seed-with-port", "--seed", rig + ["--seed", "3"]),
                  ("noise-peak-with-port", "--noise-peak", rig + ["--noise-peak", "0"]),
                  ("full-schedule-sampled", "--full-schedule", ["--full-schedule"])]]
    cases.append(Case("compare-full-schedule-continuous", "cli-compare",
                      short + ["--placement", "continuous", "--full-schedule"], expect="ok",
                      why="--full-schedule where it has an effect: the continuous placement"))
    return cases


def sweep_cases() -> list[Case]:
    def spec(text: str | bytes) -> Callable:
        return write("s.toml", text)

    remote = ["sweep", "s.toml", "--out", "out"]
    sweep = remote + ["--workers", "1"]
    built = sweep + ["--build-dir", "{build}"]  # for a spec of the built-in fig7_slow (refused with any other)
    fig7_slow = ("grid-nan", "ssp-stop-negative", "ssp-mass-grams")
    cal = '[run]\nkind = "calibration"\nsigma = [10.0, 100.0]\npoints = 20\nnodes = 41\n'
    cases = [Case(f"sweep-{name}", "toml", built if name in fig7_slow else sweep, setup=spec(text), timeout=120)
             for name, text in [
        ("binary", os.urandom(300)), ("empty", ""), ("not-toml", "[[[\n"),
        ("name-escapes", '[sweep]\nname = "../../x"\n' + cal + '[grid]\nshape = ["piston"]\n'),
        ("name-absolute", '[sweep]\nname = "/tmp/x"\n' + cal + '[grid]\nshape = ["piston"]\n'),
        ("kind-bogus", '[run]\nkind = "bogus"\n[grid]\nx = [1]\n'), ("no-grid", cal),
        ("grid-empty-list", cal + "[grid]\nshape = []\n"),
        ("grid-huge", cal + "[grid]\nnodes = [" + ",".join(str(41 + 2 * i) for i in range(400))
         + "]\nshape = [" + ",".join(f'"plate:{i}"' for i in range(1, 400)) + "]\n"),
        ("grid-nan", '[run]\nkind = "ssp"\nstop_time = 0.01\n[grid]\n"Plant.mass" = [nan]\n'),
        ("grid-unknown-key", cal + "[grid]\nbogus = [1, 2]\n"),
        ("random-negative-draws",
         cal + '[random]\ndraws = -1\nseed = 1\nnodes = {distribution = "integers", low = 41, high = 61}\n'),
        ("random-inverted",
         cal + '[random]\ndraws = 2\nseed = 1\nnodes = {distribution = "integers", low = 61, high = 41}\n'),
        ("random-bogus-distribution",
         cal + '[random]\ndraws = 2\nseed = 1\nnodes = {distribution = "cauchy", low = 1, high = 2}\n'),
        ("ssp-stop-negative", '[run]\nkind = "ssp"\nstop_time = -1\n[grid]\n"Plant.mass" = [0.13]\n'),
        ("ssp-structure-missing",
         '[run]\nkind = "ssp"\nstructure = "none.ssp"\nstop_time = 0.01\n[grid]\n"Plant.mass" = [0.13]\n'),
        ("ssp-structure-absolute-outside",
         '[run]\nkind = "ssp"\nstructure = "/etc/passwd"\nstop_time = 0.01\n[grid]\n"Plant.mass" = [0.13]\n'),
        ("unknown-table", cal + "[grid]\nshape = [\"piston\"]\n[extra]\nx = 1\n"),
        ("shape-bogus", cal + '[grid]\nshape = ["bogus"]\n'), ("shape-plate-0", cal + '[grid]\nshape = ["plate:0"]\n'),
        ("ssp-mass-grams", '[run]\nkind = "ssp"\nstop_time = 0.01\n[grid]\n"Plant.mass" = [134.7]\n'),
    ]]
    # a value a run refuses: that run is a row with its error, the others go on; exit code 1, each failure named
    for case in cases:
        if case.id in ("sweep-shape-plate-0", "sweep-ssp-mass-grams"):
            case.expect, case.exit_code = "ok", 1
            case.why = ("the run is a row with its error, named at the end; the sweep exits 1 (a grid's other runs "
                        "go on)")
            case.check = _failure_named
    cases += [
        Case("sweep-scheduler-bogus", "toml", remote + ["--scheduler", "bogus"],
             setup=spec(cal + '[grid]\nshape = ["piston"]\n')),
        Case("sweep-scheduler-unreachable", "toml", remote + ["--scheduler", "tcp://127.0.0.1:9"],
             setup=spec(cal + '[grid]\nshape = ["piston"]\n'), timeout=120),
        Case("sweep-workers-negative", "toml", sweep + ["--workers", "-1"],
             setup=spec(cal + '[grid]\nshape = ["piston"]\n')),
        Case("sweep-workers-zero", "toml", sweep + ["--workers", "0"], setup=spec(cal + '[grid]\nshape = ["piston"]\n'),
             expect="ok", why="0 workers: the runs in this process, one thread (for debugging)"),
        Case("sweep-out-is-file", "toml", sweep,
             setup=chain(spec(cal + '[grid]\nshape = ["piston"]\n'), write("out", "mine\n")), protect=("out",)),
        Case("sweep-spec-missing", "toml", ["sweep", "none.toml"]),
        Case("sweep-spec-dev-zero", "toml", ["sweep", "/dev/zero"], timeout=60),
        Case("sweep-spec-folder", "toml", ["sweep", "."]),
    ]
    # plans (issue 26): too long unless accepted, runs that cannot start, settings and options without effect
    ssp = '[run]\nkind = "ssp"\nstop_time = 0.15\n'
    masses = '[grid]\n"Plant.mass" = [' + ", ".join(f"{0.12 + 0.01 * i:.2f}" for i in range(10)) + "]\n"
    cases += [Case(f"sweep-{name}", "toml", argv, setup=spec(text), check=error_names(named))
              for name, argv, text, named in [
        ("long-1050-runs", sweep, cal + f"[grid]\nnodes = {list(range(41, 83, 2))}\npoints = {list(range(20, 70))}\n",
         "--accept-long-plan"),
        ("long-4000-s-simulated", built, ssp.replace("0.15", "400") + masses, "--accept-long-plan"),
        ("ssp-200-million-steps", built, ssp.replace("0.15", "1e5") + masses, "200,000,000 steps"),
        ("ramp-unswept", built, ssp + '[run.ramps]\n"ResonanceTracker.resonance_shift" = {duration_s = 0.1}\n' + masses,
         "has no effect"),
        ("input-constant-swept", built, ssp + '[run.inputs]\n"ResonanceTracker.resonance_shift" = 0.0\n[grid]\n'
         '"inputs.ResonanceTracker.resonance_shift" = [10.0]\n', "has no effect"),
        ("workers-with-scheduler", remote + ["--scheduler", "tcp://127.0.0.1:9", "--workers", "2"],
         cal + '[grid]\nshape = ["piston"]\n', "--workers has no effect"),
        ("build-dir-calibration", built, cal + '[grid]\nshape = ["piston"]\n', "--build-dir has no effect"),
        ("shape-file-missing", sweep, cal + '[grid]\nshape = ["none.csv"]\n', "none.csv (a path in a spec is relative"),
    ]]
    # a file a spec names, beside the spec: read from the spec's folder (not the workers'), shipped to the workers
    beside = ["sweep", "spec/s.toml", "--out", "out", "--workers", "1"]
    scan = (Path(__file__).resolve().parents[1] / "examples" / "shapes" / "vibrometer_scan.csv").read_text()
    cases += [
        Case("sweep-shape-file-beside-spec", "toml", beside, setup=files(spec__s_DOT_toml=cal + '[grid]\nshape = '
             '["scan.csv", "piston"]\n', spec__scan_DOT_csv=scan), expect="ok", timeout=120,
             why="a path in a spec is relative to the spec's folder; the file goes to the workers as the structure "
                 "does"),
        Case("sweep-calibration-file-beside-spec", "toml", beside + ["--build-dir", "{build}"], setup=files(
             spec__s_DOT_toml=ssp + '[grid]\n"Controller.calibration" = ["k.json"]\n',
             spec__k_DOT_json=json.dumps({"version": 1, "kind": "polynomial", "name": "eq. 17", "coefficients": [
                 1.2348, 0.022928, -0.0001301, 2.9826e-07, -2.4985e-10], "sigma_range": [10.0, 500.0]})),
             expect="ok", timeout=120,
             why="a Controller.calibration file beside the spec: read from there by the runs"),
    ]
    return cases


def _failure_named(folder: Path, done: subprocess.CompletedProcess) -> str | None:
    return None if "failed " in done.stdout and "1 failed" in done.stdout else "the failed run is not named"


def ssp_cases() -> list[Case]:
    def ssd(old: str, new: str, count: int = 1):
        return unpacked_fig7(lambda text: _replace(text, old, new, count))

    run = ["run", "fig7", "--stop-time", "0.02", "--out", "out"]
    run_default = ["run", "fig7", "--out", "out", "--max-steps", "100"]
    cases = [Case(f"ssd-{name}", "ssp", argv, setup=setup) for name, argv, setup in [
        ("source-dev-zero", run, ssd('source="resources/SlowPlant.fmu"', 'source="/dev/zero"')),
        ("source-outside", run, ssd('source="resources/SlowPlant.fmu"', 'source="../../SlowPlant.fmu"')),
        ("source-absolute", run,
         lambda f, b: ssd('source="resources/SlowPlant.fmu"', f'source="{b}/SlowPlant.fmu"')(f, b)),
        ("source-absolute-in-archive", ["run", "x.ssp", "--stop-time", "0.02", "--out", "out"],
         lambda f, b: _packed(f, b, 'source="resources/SlowPlant.fmu"', f'source="{b}/SlowPlant.fmu"')),
        ("source-outside-archive", ["run", "x.ssp", "--stop-time", "0.02", "--out", "out"],
         lambda f, b: _packed(f, b, 'source="resources/SlowPlant.fmu"', 'source="../SlowPlant.fmu"')),
        ("ssv-outside-archive", ["run", "x.ssp", "--stop-time", "0.02", "--out", "out"],
         lambda f, b: _packed(f, b, 'source="resources/paper_rig.ssv"', f'source="{f}/paper_rig.ssv"')),
        ("source-folder", run, ssd('source="resources/SlowPlant.fmu"', 'source="resources"')),
        ("source-missing", run, ssd('source="resources/SlowPlant.fmu"', 'source="resources/None.fmu"')),
        ("source-url", run, ssd('source="resources/SlowPlant.fmu"', 'source="http://example.invalid/x.fmu"')),
        ("ssv-source-dev-zero", run, ssd('source="resources/paper_rig.ssv"', 'source="/dev/zero"')),
        ("ssv-source-outside", run, ssd('source="resources/paper_rig.ssv"', 'source="../paper_rig.ssv"')),
        ("stop-nan", run_default, ssd('stopTime="3.7"', 'stopTime="nan"')),
        ("start-inf", run, ssd('startTime="0"', 'startTime="inf"')),
        ("start-word", run, ssd('startTime="0"', 'startTime="soon"')),
        ("xxe", run, lambda f, b: unpacked_fig7(lambda t: _xxe(t))(f, b)),
        ("billion-laughs", run, lambda f, b: unpacked_fig7(lambda t: _laughs(t))(f, b)),
        ("not-xml", run, unpacked_fig7(lambda t: "not xml at all")),
        ("binary", run, unpacked_fig7(lambda t: t.encode("utf-8").hex()[:100] + "\x00\x01")),
        ("truncated", run, unpacked_fig7(lambda t: t[: len(t) // 2])),
        ("wrong-root", run, unpacked_fig7(lambda t: "<html><body/></html>")),
        ("duplicate-element", run, ssd('name="Controller"', 'name="Plant"')),
        ("connection-unknown-connector", run, ssd('startConnector="height"', 'startConnector="heigth"')),
        ("input-two-sources", run, lambda f, b: unpacked_fig7(_second_source)(f, b)),
        ("self-reference", run, ssd('source="resources/SlowPlant.fmu"', 'source="SystemStructure.ssd"')),
    ]]
    for case in cases:
        if case.id == "ssd-source-absolute":
            case.expect = "ok"
            case.why = ("a structure given as a folder or .ssd is the user's own files: it may name an FMU anywhere on "
                        "their disk (as an .ssd of the FMI Reference FMUs does); an .ssp archive may not "
                        "(ssd-source-absolute-in-archive)")
    cases += [
        Case("ssv-misspelt-parameter", "ssv", run, setup=chain(unpacked_fig7(), lambda f, b: _edit(
            f / "fig7/resources/paper_rig.ssv", 'name="mass"', 'name="mas"'))),
        Case("ssv-mass-grams", "ssv", run, setup=chain(unpacked_fig7(), lambda f, b: _edit(
            f / "fig7/resources/paper_rig.ssv", 'value="0.1347"', 'value="134.7"'))),
        Case("ssv-mass-nan", "ssv", run, setup=chain(unpacked_fig7(), lambda f, b: _edit(
            f / "fig7/resources/paper_rig.ssv", 'value="0.1347"', 'value="NaN"'))),
        Case("ssv-mass-string", "ssv", run, setup=chain(unpacked_fig7(), lambda f, b: _edit(
            f / "fig7/resources/paper_rig.ssv", '<ssv:Real value="0.1347" unit="kg"/>',
            '<ssv:String value="heavy"/>'))),
        Case("ssv-mass-wrong-unit", "ssv", run, setup=chain(unpacked_fig7(), lambda f, b: _edit(
            f / "fig7/resources/paper_rig.ssv", 'value="0.1347" unit="kg"', 'value="0.1347" unit="m"'))),
        Case("ssv-binary", "ssv", run, setup=chain(unpacked_fig7(), lambda f, b: (f / "fig7/resources/paper_rig.ssv")
                                                   .write_bytes(os.urandom(400)))),
        Case("ssd-stop-time-honoured", "ssp", ["run", "fig7", "--out", "out", "--reference-input", "none"],
             setup=ssd('stopTime="3.7"', 'stopTime="0.01"'), expect="ok",
             why="the SSD's own DefaultExperiment stopTime (0.01 s) ends the run", check=_rows_equal(20)),
    ]
    big = b"\0" * (1 << 20)
    cases += [
        Case("ssp-zip-slip", "ssp", ["run", "x.ssp", "--stop-time", "0.02", "--out", "out"],
             setup=archive_with({"../../evil.txt": "x", "/tmp/evil-abs.txt": "x"}), expect="ok",
             why="entries with ../ or absolute names stay inside the temporary folder (the run itself is valid)",
             check=lambda f, d: "escaped" if (f.parent / "evil.txt").exists() else None),
        Case("ssp-unused-huge-entry", "ssp", ["run", "x.ssp", "--stop-time", "0.02", "--out", "out"],
             setup=_huge_entry_archive, timeout=60),
        Case("ssp-not-zip", "ssp", ["run", "x.ssp", "--out", "out"], setup=write("x.ssp", os.urandom(1000))),
        Case("ssp-empty-zip", "ssp", ["run", "x.ssp", "--out", "out"], setup=_empty_zip),
        Case("ssp-truncated", "ssp", ["run", "x.ssp", "--out", "out"], setup=_truncated_archive),
        Case("ssp-encrypted-flag", "ssp", ["run", "x.ssp", "--out", "out"], setup=_encrypted_archive),
        Case("ssp-unknown-compression", "ssp", ["run", "x.ssp", "--out", "out"], setup=_odd_compression_archive),
        Case("ssp-self-nested", "ssp", ["run", "x.ssp", "--out", "out"], setup=_self_nested_archive, timeout=60),
        Case("ssp-fmu-garbage", "ssp", ["run", "x.ssp", "--stop-time", "0.02", "--out", "out"],
             setup=archive_with({"resources/SlowPlant.fmu": big[:1000] + os.urandom(100)})),
        Case("ssp-fmu-empty-zip", "ssp", ["run", "x.ssp", "--stop-time", "0.02", "--out", "out"],
             setup=archive_with({"resources/SlowPlant.fmu": _zip_bytes({"x.txt": "x"})})),
        Case("ssp-fmu-no-binary", "ssp", ["run", "x.ssp", "--stop-time", "0.02", "--out", "out"],
             setup=_fmu_without_binary),
        Case("ssp-fmu-bad-model-description", "ssp", ["run", "x.ssp", "--stop-time", "0.02", "--out", "out"],
             setup=_fmu_bad_model_description),
        Case("ssp-directory", "ssp", ["run", ".", "--out", "out"]),
        Case("ssp-dev-zero", "ssp", ["run", "/dev/zero", "--out", "out"], timeout=60),
    ]
    return cases


def _packed(folder: Path, build: Path, old: str, new: str) -> None:
    """fig7_slow.ssp with its SSD edited, packed as x.ssp; the file the edit names outside it exists."""
    shutil.copy(build / "SlowPlant.fmu", folder / "SlowPlant.fmu")
    (folder / "paper_rig.ssv").write_text((Path(__file__).parent.parent / "ssp" / "paper_rig.ssv").read_text())
    with zipfile.ZipFile(build / "fig7_slow.ssp") as source:
        ssd = source.read("SystemStructure.ssd").decode()
    archive_with({"SystemStructure.ssd": _replace(ssd, old, new)})(folder, build)


def _replace(text: str, old: str, new: str, count: int = 1) -> str:
    if old not in text:
        raise AssertionError(f"census set-up: {old!r} not in the SSD")
    return text.replace(old, new, count)


def _edit(path: Path, old: str, new: str) -> None:
    path.write_text(_replace(path.read_text(), old, new))


def _xxe(text: str) -> str:
    text = text.split("?>", 1)[1] if text.startswith("<?xml") else text
    return ('<?xml version="1.0"?>\n<!DOCTYPE x [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>\n'
            + text.replace('name="Plant"', 'name="&xxe;"', 1))


def _laughs(text: str) -> str:
    text = text.split("?>", 1)[1] if text.startswith("<?xml") else text
    entities = '<!ENTITY a0 "lol">' + "".join(f'<!ENTITY a{i} "{("&a" + str(i - 1) + ";") * 10}">'
                                              for i in range(1, 10))
    return f'<?xml version="1.0"?>\n<!DOCTYPE x [{entities}]>\n' + text.replace('name="Plant"', 'name="&a9;"', 1)


def _second_source(text: str) -> str:
    # SensorChain.true_height is fed by Plant.height already
    return _replace(text, "</ssd:Connections>", '<ssd:Connection startElement="SensorChain" '
                    'startConnector="measured_height" endElement="SensorChain" endConnector="true_height"/>'
                    "</ssd:Connections>")


def _rows_equal(rows: int):
    def check(folder: Path, done: subprocess.CompletedProcess) -> str | None:
        got = _rows(folder / "out" / "results.csv")
        return None if got == rows + 1 or got == rows else f"{got} rows, not {rows} (stopTime ignored?)"
    return check


def _zip_bytes(entries: dict) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, data in entries.items():
            archive.writestr(name, data)
    return buffer.getvalue()


def _huge_entry_archive(folder: Path, build: Path) -> None:
    archive_with({})(folder, build)
    with zipfile.ZipFile(folder / "x.ssp", "a", zipfile.ZIP_DEFLATED, compresslevel=9) as archive:
        with archive.open("resources/unused.bin", "w", force_zip64=True) as entry:
            block = b"\0" * (64 << 20)
            for _ in range(3 * 16):  # 3 GiB of zeros: about 3 MB deflated
                entry.write(block)


def _empty_zip(folder: Path, build: Path) -> None:
    zipfile.ZipFile(folder / "x.ssp", "w").close()


def _truncated_archive(folder: Path, build: Path) -> None:
    data = (build / "fig7_slow.ssp").read_bytes()
    (folder / "x.ssp").write_bytes(data[: len(data) // 2])


def _patched_headers(central: int, local: int, patch: Callable[[bytearray, int], None]):
    """fig7_slow.ssp as x.ssp with ``patch(data, at)`` applied at this offset of every central-directory
    header and that of every local header."""
    def setup(folder: Path, build: Path) -> None:
        archive_with({})(folder, build)
        data = bytearray((folder / "x.ssp").read_bytes())
        for signature, offset in ((b"PK\x01\x02", central), (b"PK\x03\x04", local)):
            start = 0
            while (start := data.find(signature, start)) >= 0:
                patch(data, start + offset)
                start += 4
        (folder / "x.ssp").write_bytes(bytes(data))
    return setup


def _set_bit(data: bytearray, at: int) -> None:
    data[at] |= 1  # general-purpose flag bit 0: encrypted


def _method_99(data: bytearray, at: int) -> None:
    data[at:at + 2] = (99).to_bytes(2, "little")  # compression method 99 (AE-x): not one zipfile reads


_encrypted_archive = _patched_headers(8, 6, _set_bit)
_odd_compression_archive = _patched_headers(10, 8, _method_99)


def _self_nested_archive(folder: Path, build: Path) -> None:
    ssd = ('<?xml version="1.0"?><ssd:SystemStructureDescription version="1.0" name="n" '
           'xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"><ssd:System name="s"><ssd:Elements>'
           '<ssd:Component name="inner" source="resources/x.ssp" type="application/x-ssp-package"/>'
           '</ssd:Elements></ssd:System></ssd:SystemStructureDescription>')
    inner = _zip_bytes({"SystemStructure.ssd": ssd})
    for _ in range(40):
        inner = _zip_bytes({"SystemStructure.ssd": ssd, "resources/x.ssp": inner})
    (folder / "x.ssp").write_bytes(inner)


def _fmu_without_binary(folder: Path, build: Path) -> None:
    with zipfile.ZipFile(build / "SlowPlant.fmu") as fmu:
        entries = {item.filename: fmu.read(item.filename) for item in fmu.infolist()
                   if not item.filename.startswith("binaries/")}
    archive_with({"resources/SlowPlant.fmu": _zip_bytes(entries)})(folder, build)


def _fmu_bad_model_description(folder: Path, build: Path) -> None:
    with zipfile.ZipFile(build / "SlowPlant.fmu") as fmu:
        entries = {item.filename: fmu.read(item.filename) for item in fmu.infolist()}
    entries["modelDescription.xml"] = b"<fmiModelDescription><oops"
    archive_with({"resources/SlowPlant.fmu": _zip_bytes(entries)})(folder, build)


def hil_cases() -> list[Case]:
    emulator = ["rig-emulator", "--build-dir", "{build}"]
    cases = [Case(f"rig-emulator-{name}", "hil", emulator + argv, setup=setup, protect=protect)
             for name, argv, setup, protect in [
                 ("link-existing-file", ["--link", "mine.txt", "--duration", "1"], write("mine.txt", "mine\n"),
                  ("mine.txt",)),
                 ("link-existing-folder", ["--link", "d", "--duration", "1"], lambda f, b: (f / "d").mkdir(), ("d",)),
                 ("link-missing-folder", ["--link", "no/such/link", "--duration", "1"], None, ()),
                 ("link-with-url", ["--port", "loop://", "--link", "x", "--duration", "1"], None, ()),
                 ("drop-2", ["--drop", "2", "--duration", "1"], None, ()),
                 ("corrupt-negative", ["--corrupt", "-0.1", "--duration", "1"], None, ()),
                 ("duplicate-nan", ["--duplicate", "nan", "--duration", "1"], None, ()),
                 ("delay-negative", ["--delay", "-1", "--duration", "1"], None, ()),
                 ("watchdog-zero", ["--watchdog", "0", "--duration", "1"], None, ()),
                 ("ramp-negative", ["--ramp-down", "-1", "--duration", "1"], None, ()),
                 ("max-voltage-negative", ["--max-voltage", "-5", "--duration", "1"], None, ()),
                 ("duration-negative", ["--duration", "-1"], None, ()),
                 ("duration-inf", ["--duration", "inf"], None, ()),
                 ("reconnect-after-word", ["--disconnect-at", "1", "--reconnect-after", "soon", "--duration", "1"],
                  None, ()),
                 ("disconnect-negative", ["--disconnect-at", "-1", "--duration", "1"], None, ()),
                 ("truth-missing", ["--truth", "none.ssp", "--duration", "1"], None, ()),
                 ("truth-binary", ["--truth", "t.ssp", "--duration", "1"], write("t.ssp", os.urandom(300)), ()),
                 ("param-mass-grams", ["--param", "Plant.mass=134.7", "--duration", "1"], None, ()),
                 ("param-unknown", ["--param", "Plant.mas=0.1", "--duration", "1"], None, ()),
                 ("record-existing-folder", ["--record", "r.csv", "--duration", "1"],
                  lambda f, b: (f / "r.csv").mkdir(), ()),
                 ("record-bad-extension", ["--record", "r.txt", "--duration", "1"], None, ()),
                 ("port-bogus-url", ["--port", "bogus://x", "--duration", "1"], None, ()),
                 ("port-missing-device", ["--port", "/dev/nonexistent-tty", "--duration", "1"], None, ()),
                 ("rt-priority-0", ["--rt-priority", "0", "--duration", "1"], None, ()),
                 ("seed-negative", ["--seed", "-1", "--duration", "1"], None, ()),
             ]]
    garbage = [os.urandom(256) for _ in range(8)] + [b"\xa5" * 4096, b"\x7e" + b"\xff" * 3000]
    cases += [
        Case("rig-emulator-garbage-from-host", "hil", emulator + ["--duration", "1.5"],
             during=emulator_fed_garbage(garbage), expect="ok",
             why="random bytes and oversized frames from the host are dropped and counted; the rig runs on"),
        Case("rig-emulator-c-firmware-garbage-from-host", "hil", emulator + ["--firmware", "c", "--duration", "1.5"],
             during=emulator_fed_garbage(garbage), expect="ok",
             why="the C reference firmware drops and counts the same garbage (bounded buffers) and runs on"),
        Case("rig-emulator-c-firmware-with-faults", "hil",
             emulator + ["--firmware", "c", "--drop", "0.1", "--duration", "1"],
             why="faults are injected by the Python side into its own pty: refused with the C firmware, naming why"),
        Case("rig-emulator-sigterm", "hil", emulator + ["--duration", "30"], expect="ok",
             why="SIGTERM ends the emulator after its tick, with its report, the symlink removed",
             during=_signal_emulator(signal.SIGTERM), check=_link_removed, timeout=60),
        Case("rig-emulator-sighup", "hil", emulator + ["--duration", "30"], expect="ok",
             why="SIGHUP (terminal closed) ends the emulator with its report, the symlink removed",
             during=_signal_emulator(signal.SIGHUP), check=_link_removed, timeout=60),
    ]
    identify = ["identify", "--port", "{port}", "--connect-timeout", "1", "--out", "rig.json"]
    hil_run = ["run", "fig7_hil", "--build-dir", "{build}", "--stop-time", "0.2", "--out", "out",
               "--param", "proxy.port={port}", "--param", "proxy.connect_timeout=1"]
    for name, payload, close in [("random-bytes", lambda i: os.urandom(512), False),
                                 ("oversized-frames", lambda i: b"\xaa\x55" + b"\xff" * 8192, False),
                                 ("bad-crc", lambda i: bytes.fromhex("7e0201000000000000000000ff7e"), False),
                                 ("silence", lambda i: b"", False), ("closes-at-once", lambda i: b"", True)]:
        cases.append(Case(f"identify-rig-{name}", "hil", identify, setup=garbage_server(payload, close),
                          check=file_absent("rig.json"), timeout=60))
        cases.append(Case(f"run-hil-rig-{name}", "hil", hil_run, setup=garbage_server(payload, close),
                          check=summary_failed_with_reason, timeout=60))
    cases += [Case(f"identify-{name}", "cli-identify", ["identify", "--dry-run", *argv]) for name, argv in [
        ("steps-odd", ["--steps", "3"]), ("steps-negative", ["--steps", "-2"]),
        ("step-size-nan", ["--step-size", "nan"]),
        ("step-size-huge", ["--step-size", "50"]), ("max-hold-negative", ["--max-hold", "-1"]),
        ("max-voltage-inf", ["--max-voltage", "inf"]), ("metres-per-volt-zero", ["--metres-per-volt", "0"]),
        ("metres-per-volt-1e300", ["--metres-per-volt", "1e300"]), ("equilibria-mm", ["--equilibria", "50:200:12"]),
        ("equilibria-negative", ["--equilibria=-1e-4,1e-4"]), ("connect-timeout-nan", ["--connect-timeout", "nan"]),
        ("max-silence-zero", ["--max-silence", "0"]), ("time-constant-negative", ["--amplitude-time-constant", "-1"]),
        ("mass-grams", ["--mass", "134.7"]), ("connect-timeout-1e9", ["--connect-timeout", "1e9"]),
        ("max-silence-a-day", ["--max-silence", "86400"]), ("max-hold-a-day", ["--max-hold", "86400"])]]
    # plans that cannot give a result or are too long (issue 26): refused as the run would be, before a port opens
    no_rig = ["--port", "/nonexistent/port", "--out", "rig.json"]
    six = ["--equilibria", "1e-4,1e-4,1e-4,1e-4,1e-4,1e-4"]
    cases += [Case(f"identify-{name}", "cli-identify", ["identify", *argv], check=error_names(named))
              for name, argv, named in [
                  ("equilibria-six-identical", ["--dry-run", *six], "--equilibria"),
                  ("equilibria-six-identical-run", [*no_rig, *six], "--equilibria"),
                  ("equilibria-four", ["--dry-run", "--equilibria", "6e-5,9e-5,1.2e-4,1.5e-4"], "--equilibria"),
                  ("damping-one-height", ["--dry-run", "--damping-heights", "1e-4"], "--damping-heights"),
                  ("damping-one-height-run", [*no_rig, "--damping-heights", "1e-4"], "--damping-heights"),
                  ("damping-duplicates", ["--dry-run", "--damping-heights", "8e-5,8e-5,1.2e-4"], "--damping-heights"),
                  ("damping-100000-heights", ["--dry-run", "--damping-heights", "5e-5:2e-4:100000"],
                   "--damping-heights"),
                  ("steps-1000", ["--dry-run", "--steps", "1000"], "--accept-long-plan"),
                  ("steps-1000-run", [*no_rig, "--steps", "1000"], "--accept-long-plan"),
                  ("steps-10000-accepted", ["--dry-run", "--steps", "10000", "--accept-long-plan"],
                   "GiB held in memory")]]
    cases += [
        Case("identify-steps-1000-accepted", "cli-identify", ["identify", "--dry-run", "--steps", "1000",
             "--accept-long-plan"], expect="ok", why="a plan of 1.1 h the user accepted: printed with its duration"),
        Case("identify-dry-run-json", "cli-identify", ["identify", "--dry-run", "--json"], expect="ok",
             why="the default plan, as JSON"),
    ]
    short_identify = ["identify", "--port", "{port}", "--out", "rig.json", "--equilibria", "60e-6:180e-6:5",
                      "--damping-heights", "80e-6,140e-6", "--steps", "2"]
    cases += [
        Case("identify-previous-identification", "results", short_identify, setup=previous_identification,
             protect=("rig.json", "rig-raw.csv"), timeout=120),
        Case("identify-overwrite", "results", short_identify + ["--overwrite"], setup=previous_identification,
             expect="ok", why="--overwrite: the user asked to replace a previous identification", timeout=120),
        Case("identify-no-port", "cli-identify", ["identify"]),
        Case("identify-out-readonly", "cli-identify", ["identify", "--port", "/dev/null", "--out", "ro/rig.json"],
             needs_permissions=True, setup=readonly_folder),
        Case("identify-out-bad-extension", "cli-identify", ["identify", "--dry-run", "--out", "rig.txt"]),
        Case("identify-out-existing", "cli-identify", ["identify", "--port", "/nonexistent", "--out", "rig.json"],
             setup=write("rig.json", "mine\n"), protect=("rig.json",)),
    ]
    return cases


def running_emulator(folder: Path, build: Path) -> dict:
    """A rig emulator for the case (stopped after it): ``{port}`` is its pty link."""
    emulator = subprocess.Popen([sys.executable, "-m", "nfal", "rig-emulator", "--build-dir", str(build),
                                 "--watchdog", "1", "--duration", "120"], cwd=folder, stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True, start_new_session=True)

    def stop():
        emulator.terminate()
        try:
            emulator.wait(10)
        except subprocess.TimeoutExpired:
            emulator.kill()
            emulator.wait()
    return {"port": emulator.stdout.readline().strip(), "_close": (stop,)}


def previous_identification(folder: Path, build: Path) -> dict:
    (folder / "rig.json").write_text('{"mine": true}\n')
    (folder / "rig-raw.csv").write_text("time_s,height_m\n0,6e-05\n")
    return running_emulator(folder, build)


def _signal_emulator(number: int):
    def during(process: subprocess.Popen, folder: Path) -> None:
        line = process.stdout.readline().strip()
        (folder / "link.txt").write_text(line)
        if line and wait_for(lambda: os.path.exists(line), 10):
            process.stdout.readline()  # the banner: the signal handlers are in place
            os.kill(process.pid, number)
    return during


def _link_removed(folder: Path, done: subprocess.CompletedProcess) -> str | None:
    link = (folder / "link.txt").read_text().strip() if (folder / "link.txt").exists() else ""
    if not link:
        return "no link printed"
    if os.path.lexists(link):
        return f"the link {link} was left behind"
    if "ticks" not in done.stdout:  # its first two lines were read while it ran; the exit report follows
        return "no exit report"
    return None


def fmu_cases() -> list[Case]:
    slow, reynolds, tracker = "SlowPlant", "ReynoldsPlant", "ResonanceTracker"
    table = [
        (slow, "excitation-1m", {}, {"excitation_amplitude": 1.0}),
        (slow, "excitation-1e200", {}, {"excitation_amplitude": 1e200}),
        (slow, "excitation-nan", {}, {"excitation_amplitude": float("nan")}),
        (slow, "excitation-negative", {}, {"excitation_amplitude": -5e-6}),
        (slow, "drive-frequency-zero", {}, {"drive_frequency": 0.0}),
        (slow, "drive-frequency-nan", {}, {"drive_frequency": float("nan")}),
        (slow, "mass-zero", {"mass": 0.0}, {}), (slow, "mass-negative", {"mass": -1.0}, {}),
        (slow, "mass-grams", {"mass": 134.7}, {}), (slow, "mass-inf", {"mass": float("inf")}, {}),
        (slow, "radius-mm", {"radius": 50.0}, {}), (slow, "initial-height-negative", {"initial_height": -1e-5}, {}),
        (slow, "initial-height-um", {"initial_height": 60.0}, {}), (slow, "rest-gap-zero", {"rest_gap": 0.0}, {}),
        (slow, "viscosity-negative", {"viscosity": -1.0}, {}), (slow, "pressure-zero", {"ambient_pressure": 0.0}, {}),
        (slow, "gravity-nan", {"gravity": float("nan")}, {}),
        (slow, "calibration-missing", {"calibration": "none.json"}, {}),
        (slow, "calibration-dev-zero", {"calibration": "/dev/zero"}, {}),
        (slow, "near-surface-bogus", {"near_surface": "bogus"}, {}),
        (slow, "excess-damping-nan", {"excess_damping_exponent": float("nan")}, {}),
        (slow, "frequency-negative", {"nominal_frequency": -28500.0}, {}),
        (slow, "frequency-khz", {"nominal_frequency": 28.5}, {}),
        (slow, "pressure-kpa", {"ambient_pressure": 101.325}, {}), (slow, "viscosity-upas", {"viscosity": 18.1}, {}),
        (slow, "excess-damping-height-um", {"excess_damping_height": 137.0}, {}),
        (tracker, "resonance-khz", {"resonance_frequency": 28.5}, {}),
        ("SensorChain", "noise-um", {"noise_peak": 2.0}, {}),
        ("Controller", "reference-max-um", {"reference_max": 200.0}, {}),
        ("Controller", "lift-off-time-ms", {"lift_off_time": 60.0}, {}),
        (reynolds, "radial-nodes-2pow31", {"radial_nodes": 2 ** 31 - 1}, {}),
        (reynolds, "radial-nodes-0", {"radial_nodes": 0}, {}),
        (reynolds, "radial-nodes-negative", {"radial_nodes": -5}, {}),
        (reynolds, "steps-per-period-2pow31", {"steps_per_period": 2 ** 31 - 1, "film_solver": "time_marching"}, {}),
        (reynolds, "harmonics-huge", {"harmonics": 2 ** 31 - 1}, {}), (reynolds, "harmonics-0", {"harmonics": 0}, {}),
        (reynolds, "film-solver-bogus", {"film_solver": "bogus"}, {}),
        (reynolds, "shape-bogus", {"shape": "bogus"}, {}),
        (reynolds, "shape-plate-1000", {"shape": "plate:1000"}, {}),
        (reynolds, "excitation-1m", {}, {"excitation_amplitude": 1.0}),
        (reynolds, "excitation-nan", {}, {"excitation_amplitude": float("nan")}),
        (tracker, "drive-1e300", {}, {"drive_voltage": 1e300}),
        (tracker, "drive-nan", {}, {"drive_voltage": float("nan")}),
        (tracker, "drive-negative", {}, {"drive_voltage": -1e6}),
        (tracker, "shift-huge", {}, {"resonance_shift": 1e12}),
        (tracker, "q-zero", {"quality_factor": 0.0}, {}), (tracker, "q-negative", {"quality_factor": -500.0}, {}),
        (tracker, "mpv-1e300", {"metres_per_volt": 1e300}, {}), (tracker, "pll-rate-zero", {"pll_rate": 0.0}, {}),
        (tracker, "resonance-zero", {"resonance_frequency": 0.0}, {}),
        (tracker, "lock-samples-negative", {"lock_samples": -1}, {}),
        ("SensorChain", "noise-negative", {"noise_peak": -1.0}, {}),
        ("SensorChain", "noise-inf", {"noise_peak": float("inf")}, {}),
        ("SensorChain", "cutoff-zero", {"noise_cutoff": 0.0}, {}),
        ("SensorChain", "sample-rate-negative", {"sample_rate": -1.0}, {}),
        ("SensorChain", "resolution-negative", {"resolution": -1e-9}, {}),
        ("SensorChain", "true-height-nan", {}, {"true_height": float("nan")}),
        ("SensorChain", "true-height-1e300", {}, {"true_height": 1e300}),
        ("Controller", "design-bogus", {"design": "bogus"}, {}),
        ("Controller", "placement-bogus", {"placement": "bogus"}, {}),
        ("Controller", "sample-rate-zero", {"sample_rate": 0.0}, {}),
        ("Controller", "cutoff-negative", {"closed_loop_cutoff": -1.0}, {}),
        ("Controller", "max-excitation-1m", {"max_excitation": 1.0}, {}),
        ("Controller", "mass-grams", {"mass": 134.7}, {}),
        ("Controller", "reference-nan", {}, {"reference": float("nan")}),
        ("Controller", "measured-height-inf", {}, {"measured_height": float("inf")}),
        ("Controller", "calibration-binary", {"calibration": "/bin/sh"}, {}),
        ("HardwareProxy", "port-empty", {"port": ""}, {}),
        ("HardwareProxy", "port-missing", {"port": "/nonexistent"}, {}),
        ("HardwareProxy", "baud-negative", {"baud_rate": -9600, "port": "loop://"}, {}),
        ("HardwareProxy", "connect-timeout-nan", {"connect_timeout": float("nan"), "port": "loop://"}, {}),
        ("HardwareProxy", "missed-samples-negative", {"max_missed_samples": -1, "port": "loop://"}, {}),
    ]
    cases = [Case(f"fmu-{fmu}-{name}", "fmu", fmu={"fmu": fmu, "parameters": parameters, "inputs": inputs},
                  check=fmu_outputs_plausible, timeout=60) for fmu, name, parameters, inputs in table]
    leads = {"fmu-Controller-reference-max-um": "reference_max = 200.0",  # unit slips (issue 26): refused for their
             "fmu-Controller-lift-off-time-ms": "lift_off_time_s = 60.0",  # own reason, named first
             "fmu-SlowPlant-frequency-khz": "nominal_frequency = 28.5"}
    for case in cases:
        if case.id in leads:
            case.check = error_leads_with(f"[ERROR] census: {leads[case.id]} is invalid")
    cases += [
        Case("fmu-SlowPlant-free-twice", "fmu", fmu={"fmu": slow, "free_twice": True}, expect="ok",
             why="a second fmi2FreeInstance is harmless", check=fmu_outputs_plausible),
        Case("fmu-SlowPlant-step-not-dividing", "fmu", fmu={"fmu": "Controller", "step": 3e-4}),
        Case("fmu-Controller-step-negative", "fmu", fmu={"fmu": "Controller", "step": -5e-4}),
        Case("fmu-SlowPlant-step-nan", "fmu", fmu={"fmu": slow, "step": float("nan")}),
        Case("fmu-SlowPlant-step-huge", "fmu", fmu={"fmu": slow, "step": 1e9, "steps": 1,
                                                    "inputs": {"excitation_amplitude": 5e-6}},
             expect="ok", check=fmu_outputs_plausible,
             why="one 1e9 s step of a continuous plant: its adaptive integrator reaches the equilibrium (168 um at "
             "|a| = 5 um) in about 2 s; FMI bounds no step size, and the answer is right"),
        Case("fmu-SlowPlant-nominal", "fmu", fmu={"fmu": slow}, expect="ok", why="nominal parameters",
             check=fmu_outputs_plausible),
    ]
    return cases


def all_cases() -> list[Case]:
    return cli_cases() + physics_cases() + control_cases() + sweep_cases() + ssp_cases() + hil_cases() + fmu_cases()


def cases_by_id() -> dict[str, Case]:
    return {case.id: case for case in all_cases()}


