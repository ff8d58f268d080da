"""Sweeps (``nfal sweep``): spec parsing, the Dask engine locally and on a real scheduler, restarts, failures."""

from __future__ import annotations

import json
import math
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from dask.distributed import Client
from helpers.properties import examples
from helpers.warm_nfal import popen
from hypothesis import given
from hypothesis import strategies as st

from nfal.errors import SweepError, SweepSpecError
from nfal.models.reference import Staircase
from nfal.orchestration.sweep import (ResultsTable, cached_structure, columns, localised, read_table, run_sweep,
                                      run_task, shipped_files)
from nfal.orchestration.sweep_spec import expand
from nfal.apps.sweeps import KINDS, Ramp, file_in, load_spec, parse_spec

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "sweeps"
SCAN_CSV = EXAMPLES.parent / "shapes" / "vibrometer_scan.csv"

# 3 masses (one impossible: the run fails inside the worker) x 2 noise seeds, 0.15 s each.
SMALL_SSP = {
    "sweep": {"name": "small"},
    "run": {"kind": "ssp", "structure": "fig7_slow", "stop_time": 0.15, "step_size": 5e-4,
            "reference": {"levels_m": [100e-6, 140e-6], "hold_s": 0.1, "lead_s": 0.05}},
    "grid": {"Plant.mass": [0.1347, 0.16, -1.0], "SensorChain.seed": [0, 1]},
}
METRICS = ("iae_m_s", "rise_time_s", "overshoot_percent", "settling_time_s", "steady_state_error_m", "noise_rms_m")


# ------------------------------------------------------------------------------------------- spec

@pytest.mark.parametrize("name, runs", [("robustness.toml", 12), ("k_sigma.toml", 8), ("table1_grid.toml", 6)])
def test_example_specs_expand(name, runs):
    spec = load_spec(EXAMPLES / name)
    expanded = spec.runs()
    assert len(expanded) == runs
    assert len({r.run_id for r in expanded}) == runs
    assert [r.run_id for r in load_spec(EXAMPLES / name).runs()] == [r.run_id for r in expanded]


BAD_SPECS = [
    ({"run": {"kind": "fmu"}, "grid": {"a": [1]}}, "kind"),
    ({"run": {"kind": "ssp", "stop": 1.0}, "grid": {"Plant.mass": [1]}}, "stop"),
    ({"run": {"kind": "ssp", "stop_time": -1.0}, "grid": {"Plant.mass": [1]}}, "stop_time"),
    ({"run": {"kind": "ssp"}, "grid": {"mass": [1]}}, "mass"),
    ({"run": {"kind": "ssp"}, "grid": {"Plant.mass": 1.0}}, "Plant.mass"),
    ({"run": {"kind": "ssp"}, "grid": {"Plant.mass": []}}, "Plant.mass"),
    ({"run": {"kind": "ssp"}}, "nothing to sweep"),
    ({"run": {"kind": "calibration"}, "grid": {"viscosity": [1.0]}}, "viscosity"),
    ({"run": {"kind": "table1"}, "random": {"draws": 2, "mass": {"distribution": "uniform", "low": 1, "high": 2}}},
     "seed"),
    ({"run": {"kind": "table1"}, "random": {"draws": 0, "seed": 1,
                                            "mass": {"distribution": "uniform", "low": 1, "high": 2}}}, "draws"),
    ({"run": {"kind": "table1"}, "random": {"draws": 2, "seed": 1,
                                            "mass": {"distribution": "gamma", "low": 1, "high": 2}}}, "gamma"),
    ({"run": {"kind": "table1"}, "random": {"draws": 2, "seed": 1,
                                            "mass": {"distribution": "uniform", "low": 2, "high": 1}}}, "low"),
    ({"run": {"kind": "table1"}, "random": {"draws": 2, "seed": 1,
                                            "mass": {"distribution": "loguniform", "low": 0, "high": 1}}},
     "loguniform"),
    ({"run": {"kind": "table1"}, "random": {"draws": 2, "seed": 1,
                                            "mass": {"distribution": "normal", "mean": 1}}}, "std"),
    ({"run": {"kind": "table1"}, "grid": {"mass": [1.0]}, "random": {
        "draws": 2, "seed": 1, "mass": {"distribution": "uniform", "low": 1, "high": 2}}}, "both"),
    ({"run": {"kind": "table1"}, "grid": {"case": ["a", "a"]}}, "twice"),
    ({"run": {"kind": "ssp"}, "grid": {"Plant.mass": [1]}, "extra": {}}, "extra"),
    ({"grid": {"Plant.mass": [1]}}, "[run]"),
    ({"run": {"kind": "ssp", "inputs": {"ResonanceTracker.resonance_shift": "x"}}, "grid": {"Plant.mass": [1]}},
     "resonance_shift"),
    ({"run": {"kind": "ssp", "ramps": {"ResonanceTracker.resonance_shift": {"start_s": 0.1}}},
      "grid": {"Plant.mass": [1]}}, "duration_s"),
    # settings that have no effect given what is swept
    ({"run": {"kind": "ssp", "ramps": {"ResonanceTracker.resonance_shift": {"duration_s": 0.1}}},
      "grid": {"Plant.mass": [1]}}, "[run.ramps] 'ResonanceTracker.resonance_shift' has no effect without "
                                    '"inputs.ResonanceTracker.resonance_shift" swept'),
    ({"run": {"kind": "ssp", "inputs": {"ResonanceTracker.resonance_shift": 0.0}},
      "grid": {"inputs.ResonanceTracker.resonance_shift": [1.0]}},
     "[run.inputs] 'ResonanceTracker.resonance_shift' has no effect: "
     "\"inputs.ResonanceTracker.resonance_shift\" is swept"),
    # runs every one of which would be refused at its start
    ({"run": {"kind": "ssp", "stop_time": 1e5}, "grid": {"Plant.mass": [1]}},
     "[run] a run of 100000 s at step_size = 0.0005 s is 200,000,000 steps; at most 10,000,000"),
    ({"run": {"kind": "ssp", "reference": {"levels_m": [1e-4] * 2, "hold_s": 1e4}}, "grid": {"Plant.mass": [1]}},
     "steps; at most 10,000,000"),
    ({"run": {"kind": "ssp", "reference": {"levels_m": [100, 140]}}, "grid": {"Plant.mass": [1]}},
     "[run] reference.levels_m = [100, 140] is invalid: must be clearances within 1.0–1000.0 µm (did you give µm or "
     "mm as m?)"),
    ({"run": {"kind": "ssp", "reference": {"levels_m": [1e-4, "high"]}}, "grid": {"Plant.mass": [1]}},
     "[run] reference.levels_m = [0.0001, 'high'] is invalid: must be clearances within 1.0–1000.0 µm"),
]


@pytest.mark.parametrize("data, names", BAD_SPECS)
def test_bad_specs_name_the_key(data, names):
    with pytest.raises(SweepSpecError, match=re.escape(names)):
        parse_spec(data).runs()


def test_bad_toml_is_a_spec_error(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[run\nkind = 'ssp'\n")
    with pytest.raises(SweepSpecError, match="TOML"):
        load_spec(path)


@examples(40)
@given(grid=st.dictionaries(st.sampled_from(["Plant.mass", "Controller.kp", "SensorChain.seed"]),
                            st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=1, max_size=3, unique=True),
                            min_size=1, max_size=3),
       draws=st.integers(1, 4), seed=st.integers(0, 2**32))
def test_expansion_is_complete_stable_and_seeded(grid, draws, seed):
    data = {"run": {"kind": "ssp"}, "grid": grid,
            "random": {"draws": draws, "seed": seed,
                       "inputs.ResonanceTracker.resonance_shift": {"distribution": "normal", "mean": 0.0, "std": 20.0}}}
    runs = parse_spec(data).runs()
    assert len(runs) == math.prod(len(v) for v in grid.values()) * draws
    assert len({r.run_id for r in runs}) == len(runs)
    again = parse_spec(data).runs()
    assert [(r.run_id, r.parameters) for r in again] == [(r.run_id, r.parameters) for r in runs]


def test_random_draws_depend_on_the_seed():
    def shifts(seed):
        data = {"run": {"kind": "table1"}, "random": {"draws": 3, "seed": seed,
                                                      "mass": {"distribution": "uniform", "low": 1, "high": 2}}}
        return [r.parameters["mass"] for r in expand(parse_spec(data))]

    assert shifts(1) == shifts(1)
    assert shifts(1) != shifts(2)
    assert all(1 <= m <= 2 for m in shifts(3))


# ------------------------------------------------------------------------------------------- pieces

def test_ramp_holds_ramps_and_holds():
    ramp = Ramp(0.0, 10.0, 1.0, 2.0)
    assert [ramp(t) for t in (0.0, 1.0, 2.0, 3.0, 9.0)] == [0.0, 0.0, 5.0, 10.0, 10.0]


def test_cached_structure_checks_the_hash_and_unpacks_the_fmus(tmp_path, fig7_archives):
    import hashlib

    data = fig7_archives["fig7_slow"].read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    folder = cached_structure(data, sha, cache_dir=tmp_path)
    assert (folder / "SystemStructure.ssd").is_file()
    assert (folder / "resources" / "SlowPlant.fmu" / "modelDescription.xml").is_file()
    assert cached_structure(data, sha, cache_dir=tmp_path) == folder
    (folder / ".sha256").write_text("0" * 64)  # an incomplete or foreign cache entry is rebuilt
    assert cached_structure(data, sha, cache_dir=tmp_path) == folder
    assert (folder / ".sha256").read_text().strip() == sha
    with pytest.raises(SweepError, match="sha256"):
        cached_structure(data[:-1], sha, cache_dir=tmp_path / "other")


def test_a_complete_cache_entry_another_process_renamed_in_is_never_removed(tmp_path, fig7_archives, monkeypatch):
    """Two processes unpack the same archive at once: the one that finds the other's folder renamed in after its
    first look leaves that folder alone (runs are using it). Before, it removed it as an interrupted unpack: a
    local sweep's run failed with a StructureError in CI."""
    import hashlib

    from nfal.orchestration import sweep

    data = fig7_archives["fig7_slow"].read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    folder = cached_structure(data, sha, cache_dir=tmp_path)  # the other process's, complete
    (folder / "in-use").write_text("a run's\n")
    looks = [False]  # this process's first look came before the other's rename
    complete = sweep._complete
    monkeypatch.setattr(sweep, "_complete", lambda path, digest: looks.pop() if looks else complete(path, digest))
    assert cached_structure(data, sha, cache_dir=tmp_path) == folder
    assert (folder / "in-use").read_text() == "a run's\n"
    assert [p.name for p in tmp_path.iterdir()] == [sha]  # its own unpack discarded, nothing left beside


def test_a_task_runs_in_process_with_a_ramped_input(fig7_archives):
    import hashlib

    data = fig7_archives["fig7_slow"].read_bytes()
    spec = parse_spec({**SMALL_SSP, "run": {**SMALL_SSP["run"],
                                           "ramps": {"ResonanceTracker.resonance_shift": {"duration_s": 0.1}}},
                       "grid": {"inputs.ResonanceTracker.resonance_shift": [0.0, 300.0]}})
    rows = [run_task(run, KINDS["ssp"].task, data, hashlib.sha256(data).hexdigest()) for run in spec.runs()]
    assert [r["status"] for r in rows] == ["ok", "ok"], rows
    assert rows[1]["iae_m_s"] != rows[0]["iae_m_s"]  # the drift reached the loop
    bad = run_task(spec.runs()[0], KINDS["ssp"].task, data, "0" * 64)
    assert bad["status"] == "failed" and "sha256" in bad["error"]


@pytest.mark.slow  # two runs of the loop, one from rest
def test_a_sweep_row_carries_the_runs_status_and_warnings(fig7_archives, tmp_path):
    """As ``nfal run``: a level out of the drive's reach (and one reached after it) is "ok" with the warning in its
    row; an object that never lifts off (from rest, a lift-off of 10 s, the longest the Controller takes) is a failed
    row with the reason."""
    spec = parse_spec({"sweep": {"name": "status"},
                       "run": {"kind": "ssp", "structure": "fig7_slow", "stop_time": 0.08, "step_size": 5e-4,
                               "reference": {"levels_m": [60e-6, 100e-6, 60e-6], "hold_s": 0.025, "lead_s": 0.03},
                               "parameters": {"Controller.max_excitation": 2e-6, "Controller.lift_off_time": 10.0}},
                       "grid": {"Plant.initial_height": [60e-6, 5e-6]}})
    result = run_sweep(spec, tmp_path, workers=0, plot=False, archives=fig7_archives)
    warned, failed = sorted(result.rows(), key=lambda r: -r["param:Plant.initial_height"])
    assert warned["status"] == "ok" and "level 100 um (0.03-0.055 s) was never reached" in warned["warnings"]
    assert failed["status"] == "failed" and "the object never lifted off to the reference" in failed["error"]
    assert (result.summary["ok"], result.summary["with_warnings"], result.summary["failed"]) == (1, 1, 1)


def test_results_table_drops_a_cut_off_last_row(tmp_path):
    spec = parse_spec(SMALL_SSP)
    header = columns(spec)
    path = tmp_path / "results.csv"
    table = ResultsTable(path, header)
    table.append({"run_id": "r1", "index": 0, "status": "ok", "iae_m_s": 1.5})
    table.close()
    with path.open("a") as handle:
        handle.write("r2,1,ok,,0.3")  # killed mid-row
    again = ResultsTable(path, header)
    again.close()
    assert set(again.finished) == {"r1"}
    assert path.read_text().endswith("\n")
    with pytest.raises(SweepError, match="another sweep"):
        ResultsTable(path, header[:-1])


# ------------------------------------------------------------------------------------------- engine

@pytest.fixture(scope="module")
def small_spec():
    return parse_spec(SMALL_SSP)


#: The tests of the one local-cluster sweep, on one worker: the sweep runs once.
LOCAL_SWEEP_GROUP = pytest.mark.xdist_group("local_sweep")


@pytest.fixture(scope="module")
def local_sweep(small_spec, fig7_archives, tmp_path_factory):
    """The one sweep on a local cluster of worker processes; the other tests run in this process (workers=0)."""
    return run_sweep(small_spec, tmp_path_factory.mktemp("local"), workers=2, archives=fig7_archives)


def _by_id(rows):
    return {r["run_id"]: r for r in rows}


@pytest.mark.slow  # a Dask cluster of worker processes
@LOCAL_SWEEP_GROUP
def test_local_sweep_writes_one_row_per_run(local_sweep, small_spec):
    rows = local_sweep.rows()
    assert [r["run_id"] for r in rows] == [r.run_id for r in small_spec.runs()]
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(ok) == 4
    for row in ok:
        assert all(math.isfinite(row[m]) for m in METRICS)
        assert 0 < row["rise_time_s"] < 0.1 and row["wall_time_s"] > 0
    assert local_sweep.summary["ok"] == 4 and local_sweep.summary["failed"] == 2
    assert local_sweep.plot_path is not None and local_sweep.plot_path.stat().st_size > 0


@pytest.mark.slow  # a Dask cluster of worker processes
@LOCAL_SWEEP_GROUP
def test_a_run_that_raises_in_a_worker_is_a_row(local_sweep):
    failed = [r for r in local_sweep.rows() if r["status"] == "failed"]
    assert [r["param:Plant.mass"] for r in failed] == [-1.0, -1.0]
    assert all(r["error"] and r["iae_m_s"] is None for r in failed)


@pytest.mark.slow  # a Dask cluster of worker processes
@LOCAL_SWEEP_GROUP
def test_heavier_plant_rises_slower(local_sweep):
    rows = [r for r in local_sweep.rows() if r["status"] == "ok" and r["param:SensorChain.seed"] == 0]
    by_mass = sorted(rows, key=lambda r: r["param:Plant.mass"])
    assert by_mass[0]["rise_time_s"] < by_mass[1]["rise_time_s"]


@pytest.mark.slow  # a Dask cluster of worker processes
@LOCAL_SWEEP_GROUP
def test_interrupted_sweep_resumes_without_repeating(small_spec, fig7_archives, tmp_path, local_sweep):
    first: list[str] = []

    def interrupt_after_two(row):
        first.append(row["run_id"])
        if len(first) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(small_spec, tmp_path, workers=0, archives=fig7_archives, on_row=interrupt_after_two, plot=False)
    assert [r["run_id"] for r in read_table(tmp_path / "results.csv")] == sorted(
        first, key=lambda rid: next(r.index for r in small_spec.runs() if r.run_id == rid))
    second: list[str] = []
    result = run_sweep(small_spec, tmp_path, workers=0, archives=fig7_archives,
                       on_row=lambda r: second.append(r["run_id"]))
    assert result.summary["skipped"] == 2 and result.summary["new"] == 4
    assert not set(first) & set(second)
    rows = result.rows()
    assert sorted(r["run_id"] for r in rows) == sorted(r.run_id for r in small_spec.runs())
    _assert_same_table(rows, local_sweep.rows())
    third = run_sweep(small_spec, tmp_path, workers=0, archives=fig7_archives, plot=False)
    assert third.summary["new"] == 0 and len(third.rows()) == 6


def _assert_same_table(rows, reference):
    reference = _by_id(reference)
    assert set(_by_id(rows)) == set(reference)
    for row in rows:
        expected = reference[row["run_id"]]
        assert row["status"] == expected["status"]
        assert {k: v for k, v in row.items() if k.startswith("param:")} == \
            {k: v for k, v in expected.items() if k.startswith("param:")}
        for metric in METRICS:
            if expected[metric] is None:
                assert row[metric] is None
            else:
                assert row[metric] == pytest.approx(expected[metric], rel=1e-12, abs=0)


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """A real ``dask scheduler`` and two ``dask worker`` processes on loopback (no shared folder), for the tests of
    the local-sweep group (one worker: three processes started once)."""
    tmp_path = tmp_path_factory.mktemp("dask_cluster")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    dask = [sys.executable, "-m", "dask"]
    logs = [open(tmp_path / f"{name}.log", "w") for name in ("scheduler", "worker0", "worker1")]
    processes = [subprocess.Popen(dask + ["scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                                  stdout=logs[0], stderr=subprocess.STDOUT)]
    try:
        for i in (0, 1):
            local = tmp_path / f"worker{i}"
            local.mkdir()
            processes.append(subprocess.Popen(
                dask + ["worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard", "--no-nanny",
                        "--local-directory", str(local)], stdout=logs[i + 1], stderr=subprocess.STDOUT))
        from dask.distributed import Client

        deadline = time.monotonic() + 60
        while True:
            try:
                with Client(address, timeout="5s") as client:
                    client.wait_for_workers(2, timeout=60)
                break
            except (OSError, TimeoutError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.3)
        yield address
    finally:
        # the workers first: a worker whose scheduler went first waits to reconnect (15 s of every teardown here)
        for process in reversed(processes):
            process.terminate()
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                process.kill()
        for log in logs:
            log.close()


@pytest.mark.slow  # a Dask cluster of worker processes
@LOCAL_SWEEP_GROUP
def test_scheduler_sweep_gives_the_local_table(dask_cluster, small_spec, fig7_archives, local_sweep, tmp_path):
    result = run_sweep(small_spec, tmp_path / "remote", scheduler=dask_cluster, archives=fig7_archives, plot=False)
    assert result.summary["workers"] == 2 and result.summary["scheduler"] == dask_cluster
    rows = result.rows()
    with Client(dask_cluster, timeout="20s") as client:  # the rows name the processes of that cluster's workers
        processes = {f"{socket.gethostname()}:{pid}" for pid in client.run(os.getpid).values()}
    assert {r["worker"] for r in rows if r["status"] == "ok"} <= processes  # which of them ran which is Dask's choice
    _assert_same_table(rows, local_sweep.rows())


CALIBRATION_SPEC = '[run]\nkind = "calibration"\nsigma = [10.0]\npoints = 20\nnodes = 41\n[grid]\nshape = ["piston"]\n'
SSP_SPEC = '[run]\nkind = "ssp"\nstop_time = 0.4\n[grid]\n"Plant.mass" = [0.1347]\n'


@pytest.mark.parametrize("spec, argv, message", [
    (CALIBRATION_SPEC + f"nodes = {list(range(41, 83, 2))}\npoints = {list(range(20, 70))}\n", [],  # 21 x 50 runs
     "s.toml: 1,050 runs, more than 1,000 runs or 3,600 s simulated: give --accept-long-plan to run it"),
    (SSP_SPEC.replace("stop_time = 0.4", "stop_time = 400").replace("[0.1347]", "[0.12, 0.13, 0.14, 0.15, 0.16, 0.17, "
                                                                    "0.18, 0.19, 0.2, 0.21]"), [],
     "s.toml: 10 runs simulating 4,000 s in all, more than 1,000 runs or 3,600 s simulated: give --accept-long-plan"),
    (CALIBRATION_SPEC, ["--build-dir", "b"], "--build-dir has no effect with s.toml: it runs no built-in structure"),
    (SSP_SPEC.replace("stop_time", 'structure = "x.ssp"\nstop_time'), ["--build-dir", "b"],
     "--build-dir has no effect with s.toml"),
    (CALIBRATION_SPEC, ["--scheduler", "tcp://127.0.0.1:9", "--workers", "2"],
     "--workers has no effect with --scheduler (the scheduler's own workers run the sweep)"),
], ids=["1050-runs", "4000-s-simulated", "build-dir-calibration", "build-dir-archive", "workers-with-scheduler"])
def test_cli_sweep_refuses_a_long_plan_or_an_option_without_effect_before_anything_starts(tmp_path, capsys, monkeypatch,
                                                                                        spec, argv, message):
    from nfal.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(spec)
    assert main(["sweep", "s.toml", "--out", "out", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"nfal sweep: error: {message}") and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]  # no result folder, no build


def test_cli_sweep_runs_a_long_plan_when_accepted(tmp_path, capsys, monkeypatch):
    """Accepted, the long plan goes on to the cluster (here an address that is no scheduler: refused there)."""
    from nfal.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(SSP_SPEC.replace("stop_time = 0.4", "stop_time = 4000"))
    assert main(["sweep", "s.toml", "--out", "out", "--scheduler", "bogus", "--accept-long-plan"]) == 2
    assert "cannot reach the Dask scheduler" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["robustness.toml", "k_sigma.toml", "table1_grid.toml"])
def test_the_example_specs_are_short_plans(name):
    from nfal.cli.commands.sweep import _require_short

    _require_short(load_spec(EXAMPLES / name), name)


@pytest.mark.slow  # a subprocess, or whole sweeps
def test_cli_sweep_calibration(tmp_path, capsys):
    import json

    from nfal.cli import main

    spec = tmp_path / "k.toml"
    spec.write_text('[sweep]\nname = "k"\n[run]\nkind = "calibration"\nsigma = [10.0, 100.0]\npoints = 40\n'
                    '[grid]\nshape = ["piston", "plate:1", "plate:0"]\nnodes = [101]\n')
    code = main(["sweep", str(spec), "--workers", "1", "--out", str(tmp_path / "out"), "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 1 and summary["ok"] == 2 and summary["failed"] == 1
    rows = read_table(tmp_path / "out" / "results.csv")
    piston = next(r for r in rows if r["param:shape"] == "piston")
    assert 0 < piston["K_at_sigma_10"] < piston["K_at_sigma_100"] < 1.3
    assert "n = 0" in next(r for r in rows if r["status"] == "failed")["error"]
    assert main(["sweep", str(tmp_path / "missing.toml")]) == 2


@pytest.mark.slow  # a subprocess, or whole sweeps
def test_a_killed_sweep_restarts_without_repeating_or_losing_runs(tmp_path, fig7_archives, small_spec):
    """SIGKILL the whole ``nfal sweep`` process group once two rows are written, then run the spec again."""
    import os
    import signal

    spec_path = tmp_path / "small.toml"
    spec_path.write_text(
        f'[sweep]\nname = "small"\n[run]\nkind = "ssp"\nstructure = "{fig7_archives["fig7_slow"]}"\nstop_time = 0.15\n'
        'step_size = 5e-4\nreference = {levels_m = [100e-6, 140e-6], hold_s = 0.1, lead_s = 0.05}\n'
        '[grid]\n"Plant.mass" = [0.1347, 0.16, -1.0]\n"SensorChain.seed" = [0, 1]\n')
    out = tmp_path / "out"
    process = popen([sys.executable, "-m", "nfal", "sweep", str(spec_path), "--workers", "0",
                                "--out", str(out)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    csv_path = out / "results.csv"
    deadline = time.monotonic() + 60
    try:
        while time.monotonic() < deadline and process.poll() is None:
            if csv_path.exists() and csv_path.read_text().count("\n") >= 3:  # header + 2 rows
                break
            time.sleep(0.05)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=15)
    before = {r["run_id"] for r in read_table(csv_path)}
    assert 2 <= len(before) < 6
    spec = load_spec(spec_path)
    again: list[str] = []
    result = run_sweep(spec, out, workers=0, plot=False, on_row=lambda r: again.append(r["run_id"]))
    assert not before & set(again)
    ids = [r["run_id"] for r in result.rows()]
    assert len(ids) == len(set(ids)) == 6 and set(ids) == {r.run_id for r in spec.runs()}


def test_an_extended_spec_skips_its_old_runs_and_a_changed_one_keeps_their_rows(tmp_path):
    data = {"sweep": {"name": "k"}, "run": {"kind": "calibration", "sigma": [10.0], "points": 20},
            "grid": {"shape": ["piston"], "nodes": [51]}}
    first = run_sweep(parse_spec(data), tmp_path, workers=0, plot=False)
    data["grid"]["nodes"] = [51, 61]  # extended: the old run keeps its id and is skipped
    extended = run_sweep(parse_spec(data), tmp_path, workers=0, plot=False)
    data["run"]["points"] = 30       # changed settings: new ids; the old rows belong to another spec
    changed = run_sweep(parse_spec(data), tmp_path, workers=0, plot=False)
    assert first.summary["ok"] == 1
    assert (extended.summary["skipped"], extended.summary["new"], extended.summary["ok"]) == (1, 1, 2)
    assert (changed.summary["skipped"], changed.summary["other_rows"], changed.summary["ok"]) == (0, 2, 2)
    assert len(changed.rows()) == 4


def test_a_sweep_takes_the_structures_default_staircase_as_nfal_run_does():
    from nfal.apps.fig7 import DEFAULT_STAIRCASES
    from nfal.apps.sweeps import _staircase

    assert _staircase("staircase", "fig7_reynolds") == DEFAULT_STAIRCASES["fig7_reynolds"]  # within the film's reach
    assert _staircase("staircase", "some/where/fig7_slow.ssp") == Staircase()
    assert _staircase("none", "fig7_slow") is None


# ------------------------------------------------------------------------------------------- paths in a spec

@pytest.mark.parametrize("name, value, named", [
    ("shape", "scan.csv", ("", "scan.csv")), ("ReynoldsPlant.shape", "../s.csv", ("", "../s.csv")),
    ("Controller.calibration", "k.json", ("", "k.json")), ("Plant.calibration", "/abs/k.json", ("", "/abs/k.json")),
    ("Plant.calibration", "perturbation:s.csv", ("perturbation:", "s.csv")),
    ("shape", "piston", None), ("shape", "paper", None), ("shape", "plate:2", None),
    ("Plant.calibration", "paper", None),
    ("Plant.calibration", "perturbation", None), ("Plant.calibration", "perturbation:plate:2", None),
    ("HardwareProxy.port", "/dev/ttyACM0", None), ("Plant.mass", 0.1, None), ("case", "a", None),
])
def test_the_values_that_name_files(name, value, named):
    assert file_in(name, value) == named


def _spec_beside_a_file(tmp_path, text: str) -> Path:
    """s.toml in tmp_path/spec with scan.csv (a shape) and k.json (the paper's calibration) beside it."""
    from nfal.models.calibration import paper_calibration

    folder = tmp_path / "spec"
    folder.mkdir()
    (folder / "scan.csv").write_bytes(SCAN_CSV.read_bytes())
    (folder / "k.json").write_text(json.dumps({"version": 1, **paper_calibration().to_dict()}))
    (folder / "s.toml").write_text(text)
    (tmp_path / "elsewhere").mkdir()
    return folder / "s.toml"


SHAPES_SPEC = ('[run]\nkind = "calibration"\nsigma = [10.0, 100.0]\npoints = 20\nnodes = 41\n'
               '[grid]\nshape = ["scan.csv", "piston"]\n')


def test_a_path_in_a_spec_resolves_from_the_specs_folder_and_the_runs_keep_it_as_written(tmp_path, monkeypatch):
    path = _spec_beside_a_file(tmp_path, SHAPES_SPEC)
    monkeypatch.chdir(tmp_path / "elsewhere")
    spec = load_spec(Path("..") / "spec" / "s.toml")
    assert spec.files == {("shape", "scan.csv"): ("", Path("..") / "spec" / "scan.csv")}
    assert [r.parameters["shape"] for r in spec.runs()] == ["scan.csv", "piston"]
    # wherever the spec is read from
    assert [r.run_id for r in spec.runs()] == [r.run_id for r in load_spec(path).runs()]


@pytest.mark.parametrize("text, message", [
    (SHAPES_SPEC.replace("scan.csv", "none.csv"), "shape = 'none.csv': no file {folder}/none.csv (a path in a spec is "
                                                  "relative to the spec's folder)"),
    ('[run]\nkind = "ssp"\nparameters = {"Controller.calibration" = "perturbation:none.csv"}\n'
     '[grid]\n"Plant.mass" = [0.13]\n',
     "Controller.calibration = 'perturbation:none.csv': no file {folder}/none.csv"),
    ('[run]\nkind = "table1"\nshape = "nonsense"\n[grid]\ncase = ["a", "b"]\n',
     "shape = 'nonsense': no file {folder}/nonsense"),
])
def test_a_missing_file_is_refused_when_the_spec_is_read_naming_where_it_was_looked_for(tmp_path, text, message):
    path = _spec_beside_a_file(tmp_path, text)
    with pytest.raises(SweepSpecError, match=re.escape(message.format(folder=path.parent))):
        load_spec(path)


def test_a_shipped_file_is_checked_and_written_once_to_the_worker_cache(tmp_path):
    spec = load_spec(_spec_beside_a_file(tmp_path, SHAPES_SPEC))
    shipped = shipped_files(spec)
    run = localised(spec.runs()[0], shipped, tmp_path / "cache")
    local = Path(run.parameters["shape"])
    assert local.parent.parent == tmp_path / "cache" / "files" and local.name == "scan.csv"
    assert local.read_bytes() == SCAN_CSV.read_bytes()
    assert localised(spec.runs()[0], shipped, tmp_path / "cache") == run and spec.runs()[1] == localised(
        spec.runs()[1], shipped, tmp_path / "cache")  # the same copy; piston is no file
    (prefix, name, sha, data), = shipped.values()
    with pytest.raises(SweepError, match="the file scan.csv arrived with sha256"):
        localised(spec.runs()[0], {("shape", "scan.csv"): (prefix, name, sha, data[:-1])}, tmp_path / "other")


def _shape_rows(result) -> dict:
    from nfal.models.calibration import perturbation_calibration
    from nfal.models.excitation import parse_shape

    rows = {row["param:shape"]: row for row in result.rows()}
    assert [row["status"] for row in rows.values()] == ["ok", "ok"], rows
    expected = perturbation_calibration(parse_shape(str(SCAN_CSV)), (1.0, 1e5), points=20, nodes=41)
    assert rows["scan.csv"]["K_at_sigma_10"] == pytest.approx(float(expected(10.0)), rel=1e-12)
    return rows


@pytest.mark.parametrize("workers", [0, pytest.param(1, marks=pytest.mark.slow)], ids=["in-process", "processes"])
def test_a_file_beside_the_spec_reaches_the_workers_wherever_they_run(tmp_path, monkeypatch, workers):
    path = _spec_beside_a_file(tmp_path, SHAPES_SPEC)
    monkeypatch.chdir(tmp_path / "elsewhere")  # the workers' folder: no scan.csv here
    _shape_rows(run_sweep(load_spec(path), tmp_path / "out", workers=workers, plot=False))


@pytest.mark.slow  # a Dask cluster of worker processes
@LOCAL_SWEEP_GROUP
def test_a_file_beside_the_spec_reaches_a_remote_schedulers_workers(tmp_path, dask_cluster):
    path = _spec_beside_a_file(tmp_path, SHAPES_SPEC)
    _shape_rows(run_sweep(load_spec(path), tmp_path / "out", scheduler=dask_cluster, plot=False))


def test_a_controllers_calibration_file_beside_the_spec_is_read_by_its_runs(tmp_path, fig7_archives, monkeypatch):
    import hashlib

    path = _spec_beside_a_file(tmp_path, '[run]\nkind = "ssp"\nstop_time = 0.15\nreference = {levels_m = [100e-6, '
                               '140e-6], hold_s = 0.1, lead_s = 0.05}\n[grid]\n"Controller.calibration" = ["k.json", '
                               '"paper"]\n')
    monkeypatch.chdir(tmp_path / "elsewhere")
    spec = load_spec(path)
    data = fig7_archives["fig7_slow"].read_bytes()
    rows = [run_task(run, KINDS["ssp"].task, data, hashlib.sha256(data).hexdigest(), shipped_files(spec))
            for run in spec.runs()]
    assert [r["status"] for r in rows] == ["ok", "ok"], rows
    assert rows[0]["iae_m_s"] == pytest.approx(rows[1]["iae_m_s"], rel=1e-9)  # k.json holds the paper's K
