"""Every FMI 3.0 FMU survives misuse as its FMI 2.0 twin does (issue 24, item 4).

Each case is one sequence of calls a careless host makes (a second free, a step before initialisation, a
call on a freed instance, bad values), on a new instance of the FMI 2.0 and of the FMI 3.0 build of the same
slave. One FMPy process per version runs every case in turn, as a careless host goes on after its mistakes: it
must end cleanly (exit code 0: no crash at a call or at exit), and both versions must answer every call alike: ok
where the twin says ok, an error where it says error. The guard against a
call on an instance that is not live (freed, or never made) is the loader's (fmus/loader/loader.c), the
same for both versions; everything else reaches the slave, whose errors are fmi2Error / fmi3Error.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys

import pytest

from nfal.apps import host_check
from nfal.fmus import build

# one worker runs the module (its xdist group), so that its module fixtures are built once
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("fmu_misuse"),
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the loader is built for Linux only")]

SCRIPT = r'''
import json, math, sys
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
spec = json.loads(sys.argv[1])
md = read_model_description(spec["fmu"])
fmi3 = md.fmiVersion.startswith("3")
if fmi3:
    from fmpy.fmi3 import FMU3Slave as Slave
else:
    from fmpy.fmi2 import FMU2Slave as Slave
refs = {v.name: v.valueReference for v in md.modelVariables}
unzipped = extract(spec["fmu"])
def handle():
    return fmu.component
def get(name):
    return (fmu.getFloat64 if fmi3 else fmu.getReal)([refs[name]])
def set_(name, value):
    (fmu.setFloat64 if fmi3 else fmu.setReal)([refs[name]], [value])
def init():
    if fmi3:
        fmu.enterInitializationMode(startTime=0.0)
    else:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
    fmu.exitInitializationMode()
def step(size):
    global t
    fmu.doStep(currentCommunicationPoint=t, communicationStepSize=size)
    t += size
def free():
    (fmu.fmi3FreeInstance if fmi3 else fmu.fmi2FreeInstance)(handle())
operations = {
    "instantiate": lambda: fmu.instantiate(),
    "init": init,
    "step": lambda: step(5e-4),
    "step_nan": lambda: step(float("nan")),
    "step_negative": lambda: step(-5e-4),
    "get": lambda: get("height"),
    "terminate": lambda: fmu.terminate(),
    "free": free,
}
for case, calls in spec["cases"].items():
    fmu = Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName=case)
    t, answers = 0.0, []
    for operation in calls:
        name, _, argument = operation.partition(":")
        try:
            if name == "set":
                variable, value = argument.split("=")
                set_(variable, float(value))
            else:
                operations[name]()
            answers.append("ok")
        except FMICallException:
            answers.append("error")
    print(json.dumps({"case": case, "answers": answers}), flush=True)
'''

#: Case -> the calls (``set:<variable>=<value>`` sets a Float64/Real variable).
CASES = {
    "free-twice": ["instantiate", "init", "step", "terminate", "free", "free"],
    "step-before-initialisation": ["instantiate", "step", "get", "free"],
    "calls-on-a-freed-instance": ["instantiate", "init", "free", "get", "step", "terminate", "free"],
    "initialise-twice": ["instantiate", "init", "init", "step", "free"],
    "step-after-terminate": ["instantiate", "init", "step", "terminate", "step", "terminate", "free"],
    "parameter-nan": ["instantiate", "set:mass=nan", "init", "step", "free"],
    "parameter-negative": ["instantiate", "set:mass=-1", "init", "step", "free"],
    "parameter-after-initialisation": ["instantiate", "init", "set:mass=2", "step", "get", "free"],
    "input-huge": ["instantiate", "init", "set:excitation_amplitude=1e200", "step", "get", "free"],
    "input-nan": ["instantiate", "init", "set:drive_frequency=nan", "step", "get", "free"],
    "step-nan": ["instantiate", "init", "step_nan", "step", "free"],
    "step-negative": ["instantiate", "init", "step_negative", "step", "free"],
}


@pytest.fixture(scope="module")
def twins(tmp_path_factory):
    folder = tmp_path_factory.mktemp("twins")
    return {version: build.build_fmu("SlowPlant", folder / f"fmi{version}", fmi_version=version) for version in (2, 3)}


@pytest.fixture(scope="module")
def answers(twins) -> dict[int, subprocess.CompletedProcess]:
    """Per FMI version, the process that ran every case (its answers: one JSON line a case)."""
    return {version: subprocess.run([sys.executable, "-c", SCRIPT, json.dumps({"fmu": str(fmu), "cases": CASES})],
                                    capture_output=True, text=True, timeout=300) for version, fmu in twins.items()}


def _answers(done: subprocess.CompletedProcess, case: str) -> list[str]:
    """The case's answers; a process that crashed (at a case or at exit) fails every case, saying where."""
    assert done.returncode == 0, f"exit code {done.returncode}\n{done.stdout}\n{done.stderr[-3000:]}"
    answered = {line["case"]: line["answers"] for line in map(json.loads, (
        text for text in done.stdout.splitlines() if text.startswith('{"case": ')))}  # not the FMU's log
    assert case in answered, f"no answers for {case}\n{done.stdout}\n{done.stderr[-3000:]}"
    return answered[case]


@pytest.mark.parametrize("case", sorted(CASES))
def test_fmi3_survives_misuse_as_its_fmi2_twin(case, answers):
    fmi2, fmi3 = _answers(answers[2], case), _answers(answers[3], case)
    assert fmi3 == fmi2
    if case in ("free-twice", "calls-on-a-freed-instance"):  # the loader's guard: nothing reaches a freed instance
        assert fmi2[CASES[case].index("free") + 1:] == ["ok" if c == "free" else "error"
                                                        for c in CASES[case][CASES[case].index("free") + 1:]]


def errors_in_our_libraries(valgrind_log: str) -> list[str]:
    """valgrind's error reports whose stack passes through the FMU's binaries (the loader, the runtime): the
    dynamic linker's and CPython's own reports are not ours to judge."""
    reports = re.split(r"\n==\d+== \n", valgrind_log)
    return [report for report in reports[1:] if "/binaries/" in report and "HEAP SUMMARY" not in report]


@pytest.fixture(scope="module")
def lightest(tmp_path_factory):
    """The FMU whose Python imports least (numpy, not scipy or numba): under valgrind the embedded interpreter's
    imports are most of the run, so the lightest FMU is the quickest to check (the runtime and the loader are the
    same in all). ``python -X importtime -c "import nfal.fmus.reference_generator"``: 0.18 s (1.3 s while it
    imported numba's kernels; this test 41-45 s against 11-12 s now, ``python -m pytest --durations=0``)."""
    folder = tmp_path_factory.mktemp("lightest")
    return {version: build.build_fmu("ReferenceGenerator", folder / f"fmi{version}", fmi_version=version)
            for version in (2, 3)}


@pytest.mark.parametrize("version", [2, 3])
def test_the_fmus_libraries_touch_no_freed_memory_from_load_to_exit(version, lightest, tmp_path):
    """Under valgrind, in the C host (what a non-Python tool does: load, step, free, unload, exit): no invalid
    read, write or free in the loader or the runtime. The FMI 3.0 runtime's state holder was destroyed by the
    exit handlers and then assigned by its unload hook: a double free that aborted 1 in 10-40 processes
    ("corrupted double-linked list"), and valgrind shows in every run. Uses of uninitialised values are
    reported too."""
    valgrind = shutil.which("valgrind")
    assert valgrind, "this test needs valgrind: apt-get install valgrind"
    host = host_check.compile_c_host(tmp_path, version)
    runs = host_check.run_in_c_host(host, lightest[version], tmp_path, runs=1, stop_time=5e-4,
                                    wrapper=(valgrind, "--num-callers=40"))
    assert runs.exit_codes == [0], runs.first_failure[-3000:]
    stderr = runs.texts[0][1]
    assert "ERROR SUMMARY" in stderr, stderr[-2000:]
    assert errors_in_our_libraries(stderr) == [], errors_in_our_libraries(stderr)[0]
