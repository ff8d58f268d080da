"""Hostile and careless input (issue 18): at least one case of each class the census found, run as a user would.

Each case is the real command line (or an FMU through fmpy) on a hostile input, taken from
tests/hostile_cases.py, the list tests/hostile_census.py runs in full. A case fails on a Python traceback
(or the CLI's "internal error"), a hang (its timeout), a crash (killed by a signal), a file that existed
before it changed or gone, or an input accepted that should be refused (or a valid one refused). Cases
refused before anything is loaded run in this process (fast); the others in their own, with a timeout.
"""

from __future__ import annotations

import os
import subprocess

import pytest

from helpers.warm_nfal import popen
from hostile_cases import (CLEAR, CRASH, HANDLED, REFUSED, TRACEBACK, WRONG, Case, cases_by_id, classify, run_case,
                           run_case_in_process, write)

CASES = cases_by_id()

#: Refused at the command line, while a file is read or as the FMUs are set up (as the suite's other ``nfal run``
#: tests, through :func:`nfal.cli.main`): run in this process.
IN_PROCESS = {
    "crashes and hangs": ["calibrate-sigma-huge-count", "design-heights-huge-count", "compare-hold-huge",
                          "sweep-spec-dev-zero"],
    "tracebacks": ["run-stop-time-nan", "run-start-time-inf", "run-plot-extension", "calibrate-shape-plate-1000",
                   "sweep-binary", "sweep-scheduler-bogus", "design-calibration-deep-json",
                   "identify-steps-10000-accepted"],
    "silently wrong": ["identify-metres-per-volt-1e300", "identify-mass-grams", "identify-out-bad-extension",
                       "rig-emulator-seed-negative", "rig-emulator-duration-negative", "calibrate-nodes-0",
                       "calibrate-experimental-mpv-1e300", "calibrate-experimental-duplicate-column",
                       "calibrate-experimental-mm-heights", "design-calibration-k-zero", "compare-max-excitation-1m",
                       "sweep-ssp-structure-absolute-outside",
                       # plans (issue 26): checked before anything runs
                       "identify-equilibria-six-identical-run", "identify-damping-one-height",
                       "identify-damping-100000-heights", "identify-steps-1000", "identify-steps-1000-accepted",
                       "compare-runs-dir-without-port", "compare-seed-with-port", "sweep-long-1050-runs",
                       "sweep-ssp-200-million-steps", "sweep-ramp-unswept", "sweep-workers-with-scheduler",
                       "sweep-shape-file-missing",
                       # unit slips and calibration fields (issue 26)
                       "design-calibration-damping-um", "design-calibration-version-true",
                       "design-calibration-factor-true", "design-calibration-rig-khz",
                       "design-calibration-entry-misspelt", "design-frequency-khz", "compare-noise-um",
                       # nfal run, refused as its archive or parameters are read
                       "run-param-seed-2pow32", "ssv-misspelt-parameter", "ssd-source-absolute-in-archive"],
    "data lost": ["sweep-name-escapes", "calibrate-out-existing-file"],
    "misleading messages": ["ssp-not-zip", "run-max-steps-0", "rig-emulator-c-firmware-with-faults",
                            "design-calibration-short-identification"],
    "valid refused": ["design-calibration-identified"],
}

#: nfal run in this process too, refused as the FMUs are set up (or a 20-row run): 0.5-2 s each, so slow, as the
#: suite's other nfal runs.
IN_PROCESS_WITH_FMUS = {
    "silently wrong": ["run-param-calibration-k-zero", "run-param-max-excitation-1m", "run-param-mass-grams",
                       "ssd-stop-time-honoured", "run-generator-levels-mm", "run-generator-table-outside",
                       "run-param-calibration-damping-um"],
    "misleading messages": ["run-param-calibration-short", "run-param-mass-negative-cause-first"],
}

#: Cases that start processes or threads, write under a limit, may hang, or may crash (an FMU's library, a foreign
#: file's parser, a signal): each in its own process.
OWN_PROCESS = {
    "data lost": ["run-out-previous-run-fails-at-start", "run-out-overwrite-keeps-other-files",
                  "identify-previous-identification", "rig-emulator-link-existing-file", "rig-emulator-sighup",
                  "run-sigterm", "run-out-full-disk"],
    "silently wrong": ["fmu-SlowPlant-excitation-1m", "fmu-ResonanceTracker-drive-1e300",
                       "fmu-ResonanceTracker-mpv-1e300", "fmu-SensorChain-true-height-1e300",
                       "fmu-SlowPlant-excess-damping-nan",
                       "sweep-shape-file-beside-spec",  # read from the workers' folder before issue 26
                       "fmu-SlowPlant-frequency-khz", "fmu-Controller-reference-max-um"],
    "crashes and hangs": ["ssd-source-dev-zero", "run-param-calibration-dev-zero", "run-stop-1e9",
                          "fmu-SlowPlant-excitation-1e200", "fmu-ReynoldsPlant-radial-nodes-2pow31",
                          "fmu-SlowPlant-free-twice", "ssp-self-nested", "rig-emulator-c-firmware-garbage-from-host"],
    "tracebacks": ["ssp-encrypted-flag", "ssp-unknown-compression", "identify-rig-random-bytes"],
}


def _ids(groups: dict[str, list[str]], *marks) -> list:
    return [pytest.param(case_id, id=f"{kind}: {case_id}", marks=marks) for kind, ids in groups.items()
            for case_id in ids]


@pytest.fixture(scope="module")
def build(fig7_archives):
    return fig7_archives["fig7_slow"].parent


def _expected(case_id: str) -> str:
    return CLEAR if CASES[case_id].expect == "error" else HANDLED


def _skip_if_meaningless(case_id: str) -> None:
    if CASES[case_id].needs_permissions and os.geteuid() == 0:
        pytest.skip("a read-only folder does not stop root")


@pytest.mark.parametrize("case_id", _ids(IN_PROCESS) + _ids(IN_PROCESS_WITH_FMUS, pytest.mark.slow))
def test_hostile_input_in_process(case_id, build, tmp_path):
    _skip_if_meaningless(case_id)
    outcome = run_case_in_process(CASES[case_id], tmp_path, build)
    assert outcome.outcome == _expected(case_id), outcome.detail


@pytest.mark.slow  # a subprocess per case
@pytest.mark.parametrize("case_id", _ids(OWN_PROCESS))
def test_hostile_input_in_its_own_process(case_id, build, tmp_path):
    _skip_if_meaningless(case_id)
    outcome = run_case(CASES[case_id], tmp_path, build, popen)
    assert outcome.outcome == _expected(case_id), outcome.detail


def test_every_listed_case_exists_and_each_class_has_one():
    listed = [case_id for groups in (IN_PROCESS, IN_PROCESS_WITH_FMUS, OWN_PROCESS) for ids in groups.values()
              for case_id in ids]
    assert not [case_id for case_id in listed if case_id not in CASES]
    assert {"data lost", "silently wrong", "crashes and hangs", "tracebacks"} <= set(IN_PROCESS) | set(OWN_PROCESS)


@pytest.mark.parametrize("returncode, stderr, expect, outcome", [
    (2, "usage: nfal run\nnfal run: error: argument --step: '0': must be > 0\n", "error", CLEAR),
    (2, "Traceback (most recent call last):\n  File x\nValueError: x\n", "error", TRACEBACK),
    (1, "nfal run: internal error: KeyError: 'x' (rerun with --debug for the traceback, and please report it)\n",
     "error", TRACEBACK),
    (-9, "", "error", CRASH),
    (0, "", "error", WRONG),
    (1, "something went wrong\n", "error", WRONG),
    (2, "nfal run: error: no\n", "ok", REFUSED),
    (0, "", "ok", HANDLED),
])
def test_the_judge(tmp_path, returncode, stderr, expect, outcome):
    """The classification itself: each kind of failure is seen as one (so the cases above can fail)."""
    case = Case("judge", "judge", ["run"], expect=expect)
    done = subprocess.CompletedProcess(["nfal", "run"], returncode, "", stderr)
    assert classify(case, done, {}, {}, tmp_path)[0] == outcome


@pytest.mark.parametrize("stdout, outcome", [("[ERROR] x: mass = -1.0 is invalid: ... (in doStep at t = 0 s)\n", CLEAR),
                                             ("", WRONG)])
def test_the_judge_wants_an_fmus_reason(tmp_path, stdout, outcome):
    case = Case("judge", "judge", fmu={"fmu": "SlowPlant"})
    done = subprocess.CompletedProcess(["python"], 2, stdout, "fmu: error: doStep: fmi2DoStep failed\n")
    assert classify(case, done, {}, {}, tmp_path)[0] == outcome


def test_the_judge_sees_a_changed_file(tmp_path, build):
    case = Case("loses", "judge", ["calibrate", "numerical", "--sigma", "10,30,100,300", "--out", "k.json"],
                setup=write("k.json", "mine\n"), protect=("k.json",), expect="ok")
    assert run_case_in_process(case, tmp_path, build).outcome == WRONG
