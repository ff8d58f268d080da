"""Co-simulation benchmarks: the Fig. 7 loop as FMUs, ours against OSP libcosim. Prints markdown tables.

    python bench/bench_cosim.py [--quick] [--repeats N]

Goals (issue): wall time of the default run (fig7_slow, 3.7 s of simulated time at 0.5 ms); the
orchestrator's overhead per FMU step; the same .ssp in libcosimpy, measured in the same run: ours
within 1.2x of libcosim's wall time.

One archive, built into an empty temporary folder by the timed ``nfal run`` (a subprocess), serves
every case. After one short warm-up of each host (not reported: the FMUs' slave modules, numpy, scipy
and python-control are imported once per process, whichever host loads them first), each case is
timed best of ``--repeats`` (default 3), the repeats interleaved, in this process, except libcosim with
OPENBLAS_NUM_THREADS=1 (a child process: the setting must precede numpy's import). Then one more run
of each host with every FMU call timed in place splits the wall time (:class:`Clocks`).
--quick: 0.3 s of simulated time.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import record
from machine import describe

from nfal.fmus.bundle_loader import REGISTRY
from nfal.models.reference import Staircase
from nfal.orchestration import run_structure
from nfal.orchestration.libcosim import run_ssp
from nfal.orchestration.master import Master
from nfal.orchestration.resolve import resolve
from nfal.orchestration.ssp import read_ssp

STEP = 5e-4
REFERENCE = "Controller.reference"


def load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f}, {five:.2f}, {fifteen:.2f}"


# --- the cases ------------------------------------------------------------------------------------

def ours(archive: Path, stop: float, algorithm: str, out_dir: Path) -> tuple[float, object]:
    """``run_structure`` as a library call, plot=False; it always streams results.csv and summary.json."""
    started = time.perf_counter()
    result = run_structure(archive, stop_time=stop, step_size=STEP, inputs={REFERENCE: Staircase()},
                           algorithm=algorithm, out_dir=out_dir, plot=False, progress=False)
    return time.perf_counter() - started, result


def libcosim(archive: Path, stop: float) -> tuple[float, object]:
    """``run_ssp``: libcosim loads the .ssp, the reference is set every step (override manipulator) and
    every output is recorded after every step (last-value observer), into numpy arrays, nothing written."""
    started = time.perf_counter()
    run = run_ssp(archive, stop, step_size=STEP, inputs={REFERENCE: Staircase()})
    return time.perf_counter() - started, run


def libcosim_bare(archive: Path, stop: float) -> tuple[float, float, float]:
    """libcosim alone: no observer, and the steps between two reference changes in one ``step(n)`` call
    (no Python per step); the same bindings as ``run_ssp``. libcosim initialises the FMUs inside the
    first step, so that step is timed apart. Returns (wall time, first step, the other steps)."""
    from libcosimpy import CosimLogging
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimManipulator import CosimManipulator

    from nfal.orchestration.libcosim import _apply_bindings, _bindings, _Variables
    from nfal.orchestration.ssp import read_ssp

    CosimLogging.log_output_level(CosimLogging.CosimLogLevel.ERROR)  # as run_ssp
    started = time.perf_counter()
    with read_ssp(archive) as structure:
        bindings = _bindings(structure.system)
    execution = CosimExecution.from_ssp_file(str(archive), round(STEP * 1e9))
    variables = _Variables(execution)
    _apply_bindings(execution, variables, bindings)
    manipulator = CosimManipulator.create_override()
    execution.add_manipulator(manipulator)
    reference, driven = Staircase(), variables[REFERENCE]
    steps = int(round(stop / STEP))
    bounds = sorted({1, *(int(round(t / STEP)) for t in reference.step_times_s if t < stop - 1e-12), steps})
    timings = []
    done = 0
    for until in bounds:
        manipulator.slave_real_values(driven.slave, [driven.reference], [float(reference(done * STEP))])
        begin = time.perf_counter()
        if not execution.step(until - done):
            raise RuntimeError(f"libcosim failed after step {done}")
        timings.append(time.perf_counter() - begin)
        done = until
    del execution
    return time.perf_counter() - started, timings[0], sum(timings[1:])


class TolerantSensorCache:
    """What-if, in this process only: the SensorChain model's transition cache (keyed on the exact step
    size) accepts a step within 1e-9 relative of the cached one. libcosim passes doStep a step size
    computed as the difference of two double time points (0.0005000000000000004, 0.0004999999999999449,
    ...), so the SensorChain FMU recomputes scipy.linalg.expm at almost every step there; our master
    passes 0.0005 exactly. The FMUs use this process's ``nfal.models`` (one module per name)."""

    def __enter__(self) -> "TolerantSensorCache":
        from nfal.models.sensor_chain import SensorChain

        self.cls, self.original = SensorChain, SensorChain.__dict__["_transition"]
        original = self.original

        def transition(chain, dt_s):
            cached = chain._cache
            if cached is not None and abs(cached[0] - dt_s) <= 1e-9 * cached[0]:
                dt_s = cached[0]
            return original(chain, dt_s)

        SensorChain._transition = transition
        return self

    def __exit__(self, *exc) -> None:
        self.cls._transition = self.original


def libcosim_patched(archive: Path, stop: float) -> tuple[float, object]:
    with TolerantSensorCache():
        return libcosim(archive, stop)


def libcosim_child(archive: Path, stop: float, repeats: int, environment: dict[str, str]) -> float:
    """Best-of wall time of ``run_ssp`` in a child process with ``environment`` added (e.g. a BLAS setting
    that must be set before numpy loads): this script with ``--libcosim-only``."""
    command = [sys.executable, __file__, "--libcosim-only", str(archive), "--stop", repr(stop),
               "--repeats", str(repeats)]
    done = subprocess.run(command, capture_output=True, text=True, env={**os.environ, **environment})
    if done.returncode != 0:
        raise RuntimeError(f"child failed ({done.returncode}): {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])["best_wall_s"]


def bare_loop(archive: Path, stop: float, algorithm: str) -> dict:
    """The same fmpy calls as the master's loop, by hand: our Master sets up and initialises the FMUs;
    then a minimal loop makes the same doStep/get/set calls with the same values (reference precomputed)
    and times every call. Returns the loop's wall time and the time inside the calls."""
    reference = Staircase()
    steps = int(round(stop / STEP))
    with read_ssp(archive) as structure:
        system = resolve(structure)
        with Master(system, step_size=STEP, algorithm=algorithm, inputs={REFERENCE: reference}) as master:
            master.instantiate()
            master.initialize(0.0, steps * STEP)
            row = master.row
            column = next(c for c, spec in enumerate(master.columns) if spec.name == REFERENCE)
            driven = [float(v) for v in reference(np.arange(steps + 1) * STEP)]
            do_steps = [(slave.fmu.fmi2DoStep, slave.component) for slave in master.slaves]
            sweep = [(t.kind == "get", t.function, t.component, t.vr, t.n, t.buffer, t.pairs) for t in master.sweep]
            gets = [op for op in sweep if op[0]]
            sets = [op for op in sweep if not op[0]]
            clock = time.perf_counter
            in_step = in_exchange = 0.0
            started = clock()
            for k in range(steps):
                t = k * STEP
                if algorithm == "jacobi":
                    for _, function, component, vr, n, buffer, _ in sets:
                        begin = clock()
                        function(component, vr, n, buffer)
                        in_exchange += clock() - begin
                for function, component in do_steps:
                    begin = clock()
                    function(component, t, STEP, 1)
                    in_step += clock() - begin
                row[column] = driven[k + 1]
                for is_get, function, component, vr, n, buffer, pairs in (sweep if algorithm == "causal" else gets):
                    if is_get:
                        begin = clock()
                        function(component, vr, n, buffer)
                        in_exchange += clock() - begin
                        for j, c in pairs:
                            row[c] = buffer[j]
                    else:
                        for j, c in pairs:
                            buffer[j] = row[c]
                        begin = clock()
                        function(component, vr, n, buffer)
                        in_exchange += clock() - begin
                if algorithm == "jacobi":
                    for _, _, _, _, _, buffer, pairs in sets:
                        for j, c in pairs:
                            buffer[j] = row[c]
            loop = clock() - started
            calls = len(sweep)
            height = row[next(c for c, spec in enumerate(master.columns) if spec.name == "Plant.height")]
    return {"loop": loop, "do_step": in_step, "exchange": in_exchange, "fmus": len(do_steps), "calls": calls,
            "steps": steps, "final_height": height}


def pure_python(stop: float) -> tuple[float, float, object]:
    """simulate_closed_loop as ``nfal compare`` builds it (gain-scheduled, realisable, paper calibration,
    coloured noise seed 0), over the same staircase up to ``stop``. Returns (wall, of it the loop, run)."""
    from nfal.models.calibration import paper_calibration
    from nfal.models.closed_loop import simulate_closed_loop
    from nfal.models.control_law import DiscreteControlLaw
    from nfal.models.measurement_noise import coloured_noise
    from nfal.models.pid_design import DesignSpec, design_schedule
    from nfal.models.plant import SimplifiedPlant
    from nfal.models.rig import RigParameters
    from nfal.models.stability import realizable_schedule

    reference = Staircase()
    if stop < reference.duration_s - 1e-12:  # --quick: the first 0.3 s of the same staircase
        reference = Staircase(reference.levels_m[:2], hold_s=stop - reference.lead_s, lead_s=reference.lead_s)
    started = time.perf_counter()
    rig, calibration = RigParameters(), paper_calibration()
    plant = SimplifiedPlant(rig, calibration)
    gains = realizable_schedule(design_schedule(None, rig, calibration, DesignSpec(10.0, 300.0)), rig,
                                sample_rate_hz=2000.0)
    law = DiscreteControlLaw(gains, sample_rate_hz=2000.0, max_excitation_m=10e-6, reference_range_m=(50e-6, 200e-6))
    noise = coloured_noise(reference.samples(2000.0), sample_rate_hz=2000.0, cutoff_hz=300.0, peak_m=2e-6, seed=0)
    begin = time.perf_counter()
    run = simulate_closed_loop(law, plant, reference, noise)
    end = time.perf_counter()
    return end - started, end - begin, run


def nfal_run(folder: Path, stop: float, quick: bool) -> tuple[float, dict]:
    """``nfal run`` (python -m nfal) end to end in a subprocess, from an empty build folder."""
    command = [sys.executable, "-m", "nfal", "run", "--build-dir", str(folder / "build"), "--out", str(folder / "run"),
               "--json"]
    if quick:
        command += ["--stop-time", f"{stop:g}"]
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"nfal run failed ({done.returncode}): {done.stderr[-2000:]}")
    return wall, json.loads((folder / "run" / "summary.json").read_text())


# --- where the time goes: every FMU call timed in place ------------------------------------------------

SLAVE_METHODS = ("setup_experiment", "enter_initialization_mode", "exit_initialization_mode", "do_step",
                 "set_real", "set_integer", "set_boolean", "set_string",
                 "get_real", "get_integer", "get_boolean", "get_string")


class Clocks:
    """Times, in this process, (1) the Python side of every FMI call of every nfal FMU, whichever host
    makes it, and (2) our master's get/set calls at the call site (fmpy; its doStep calls are timed by
    the master itself, ``summary["do_step_wall_time_s"]``).

    (1): each FMU runs on the nfal it carries (``nfal.fmus.bundle_loader``), so the ``NfalSlave`` its slave
    class derives from is patched as the loader registers the FMU (fmpy's and libcosim's alike). A call made
    before the instance's ``exit_initialization_mode`` counts as setup, the others as loop; ``first``/``last``
    bound the doStep calls in wall-clock time. (2): ``_Transfer`` objects get a timed ``function``; only calls
    after the first doStep count. Adds ~1 us per call."""

    def __init__(self) -> None:
        import nfal.orchestration.master as master

        self.transfer = master._Transfer
        self.saved: dict[tuple[type, str], object] = {}
        self.fmu_setup = self.fmu_loop = self.exchange = 0.0
        self.first = self.last = None

    def _patch(self, base: type) -> None:
        """Time ``base``'s SLAVE_METHODS (an FMU's own ``NfalSlave``)."""
        clock = time.perf_counter
        for name in SLAVE_METHODS:
            original = base.__dict__[name]
            self.saved[(base, name)] = original

            def timed(slave, *args, _original=original, _step=name == "do_step"):
                running = getattr(slave, "initialized", False)
                begin = clock()
                try:
                    return _original(slave, *args)
                finally:
                    end = clock()
                    if running:
                        self.fmu_loop += end - begin
                    else:
                        self.fmu_setup += end - begin
                    if _step:
                        self.first = begin if self.first is None else self.first
                        self.last = end

            setattr(base, name, timed)

    def _patch_module(self, module) -> None:
        """Patch the NfalSlave under each slave class of an FMU's slave module (once each)."""
        for value in vars(module).values():
            for base in value.__mro__ if isinstance(value, type) else ():
                if base.__name__ == "NfalSlave" and (base, "do_step") not in self.saved:
                    self._patch(base)

    def __enter__(self) -> "Clocks":
        from nfal.fmus.bundle_loader import _registry

        clocks, bundles = self, _registry().bundles  # the loader's registry (made if no FMU was loaded yet)

        class Patching(dict):
            """The loader's registry: each FMU's slave module patched as it is registered."""

            def __setitem__(self, key, module) -> None:
                super().__setitem__(key, module)
                clocks._patch_module(module)

        for module in bundles.values():  # FMUs loaded before, and loaded again from the same folder
            self._patch_module(module)
        self._bundles = bundles
        sys.modules[REGISTRY].bundles = Patching(bundles)
        clock = time.perf_counter
        init = self.transfer.__init__
        self.saved[(self.transfer, "__init__")] = init

        def transfer_init(transfer, *args, **kwargs):
            init(transfer, *args, **kwargs)
            function = transfer.function

            def timed_call(*call_args):
                begin = clock()
                try:
                    return function(*call_args)
                finally:
                    if self.first is not None:
                        self.exchange += clock() - begin

            transfer.function = timed_call

        self.transfer.__init__ = transfer_init
        return self

    def __exit__(self, *exc) -> None:
        sys.modules[REGISTRY].bundles = self._bundles
        for (owner, name), original in self.saved.items():
            setattr(owner, name, original)


def where_time_goes(case) -> dict:
    """Run ``case()`` once under :class:`Clocks` and split its wall time; "result" is what case returned."""
    with Clocks() as clocks:
        started = time.perf_counter()
        result = case()
        wall = time.perf_counter() - started
    if clocks.first is None:
        raise RuntimeError("no doStep seen: the FMUs do not use this process's nfal.fmus.base")
    return {"wall": wall, "before": clocks.first - started, "loop": clocks.last - clocks.first,
            "after": started + wall - clocks.last, "fmu_setup": clocks.fmu_setup, "fmu_loop": clocks.fmu_loop,
            "exchange": clocks.exchange, "result": result}


# --- main -----------------------------------------------------------------------------------------

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="0.3 s of simulated time instead of 3.7 s")
    parser.add_argument("--repeats", type=int, default=3, help="best of this many (default 3)")
    parser.add_argument("--libcosim-only", metavar="SSP", help=argparse.SUPPRESS)  # the child of libcosim_child
    parser.add_argument("--stop", type=float, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.libcosim_only:
        libcosim(Path(args.libcosim_only), 0.01)  # warm-up, as in the parent
        walls = [libcosim(Path(args.libcosim_only), args.stop)[0] for _ in range(args.repeats)]
        print(json.dumps({"best_wall_s": min(walls)}))
        return
    stop = 0.3 if args.quick else Staircase().duration_s
    steps = int(round(stop / STEP))
    fmu_steps = 4 * steps
    print(f"Machine: {describe()}; {load()} at the start", flush=True)
    holder = tempfile.TemporaryDirectory(prefix="nfal-bench-cosim-")  # removed at the end
    tmp = Path(holder.name)
    # (5) nfal run end to end from an empty build folder; its archive serves every other case.
    e2e_wall, e2e_summary = nfal_run(tmp / "e2e", stop, args.quick)
    archive = tmp / "e2e" / "build" / "fig7_slow.ssp"
    # warm-up, not reported
    ours(archive, 0.01, "causal", tmp / "warm")
    libcosim(archive, 0.01)

    runs: dict[str, list] = {k: [] for k in ("causal", "jacobi", "libcosim", "libcosim_patched", "libcosim_bare",
                                             "bare_causal", "bare_jacobi", "python")}
    for repeat in range(args.repeats):
        for algorithm in ("causal", "jacobi"):
            runs[algorithm].append(ours(archive, stop, algorithm, tmp / f"{algorithm}-{repeat}"))
        runs["libcosim"].append(libcosim(archive, stop))
        runs["libcosim_patched"].append(libcosim_patched(archive, stop))
        runs["libcosim_bare"].append(libcosim_bare(archive, stop))
        for algorithm in ("causal", "jacobi"):
            runs[f"bare_{algorithm}"].append(bare_loop(archive, stop, algorithm))
        runs["python"].append(pure_python(stop))
        print(f"repeat {repeat + 1}/{args.repeats} done; {load()}", file=sys.stderr, flush=True)
    blas1 = libcosim_child(archive, stop, args.repeats, {"OPENBLAS_NUM_THREADS": "1"})
    split = {
        "causal": where_time_goes(lambda: ours(archive, stop, "causal", tmp / "split-causal")[1]),
        "jacobi": where_time_goes(lambda: ours(archive, stop, "jacobi", tmp / "split-jacobi")[1]),
        "libcosim": where_time_goes(lambda: libcosim(archive, stop)),
        "libcosim_patched": where_time_goes(lambda: libcosim_patched(archive, stop)),
        "libcosim_bare": where_time_goes(lambda: libcosim_bare(archive, stop)),
    }
    end_load = load()

    lib_wall, lib_run = min(runs["libcosim"], key=lambda r: r[0])
    rows = [("libcosim: run_ssp, reference by override manipulator, every output observed (**baseline**)", lib_wall,
             "1.00", f"{lib_wall / steps * 1e6:.0f} us per communication step all in")]
    overhead_rows = []
    for algorithm in ("causal", "jacobi"):
        wall, result = min(runs[algorithm], key=lambda r: r[0])
        s = result.summary
        bare = runs[f"bare_{algorithm}"]
        in_calls = min(b["do_step"] + b["exchange"] for b in bare)
        overhead = s["loop_wall_time_s"] - in_calls
        notes = (f"before the loop {wall - s['loop_wall_time_s']:.2f} s (of it instantiate + initialise "
                 f"{s['initialization_wall_time_s']:.2f}), loop {s['loop_wall_time_s']:.2f} s (doStep calls "
                 f"{s['do_step_wall_time_s']:.2f})")
        if algorithm == "jacobi":
            gap = np.max(np.abs(result["Plant.height"][1:] - lib_run["Plant.height"]))
            notes += f"; max abs height difference to libcosim {gap:.1e} m"
        rows.append((f"ours, `{algorithm}`: run_structure, plot=False (results.csv is still streamed)", wall,
                     f"**{wall / lib_wall:.2f}**", notes))
        t = split[algorithm]
        do_step = t["result"].summary["do_step_wall_time_s"]
        same_run = t["loop"] - do_step - t["exchange"]
        same = all(b["final_height"] == result["Plant.height"][-1] for b in bare)
        overhead_rows.append((
            f"`{algorithm}` orchestrator overhead: the loop minus the time inside its FMU calls ({steps} x 4 doStep, "
            f"{steps} x {bare[0]['calls']} get/set), timed at our call sites in one run", same_run, "-",
            f"**{same_run / fmu_steps * 1e6:.1f} us per FMU step** ({same_run / steps * 1e6:.0f} us per communication "
            f"step): loop {t['loop']:.2f} s = doStep calls {do_step:.2f} + get/set calls {t['exchange']:.2f} + the "
            f"rest. Cross-check, a bare fmpy loop making the same calls with the same values (final height "
            f"{'equal' if same else 'DIFFERENT'}), best of {len(bare)}: FMU calls {in_calls:.2f} s, that loop all in "
            f"{min(b['loop'] for b in bare):.2f} s; ours' best loop minus these calls: "
            f"{overhead / fmu_steps * 1e6:.1f} us per FMU step"))
    lb_wall, lb_first, lb_rest = min(runs["libcosim_bare"], key=lambda r: r[0])
    patched_wall = min(w for w, _ in runs["libcosim_patched"])
    ours_wall = {a: min(w for w, _ in runs[a]) for a in ("causal", "jacobi")}
    py_wall, py_loop, py_run = min(runs["python"], key=lambda r: r[0])
    e2e_run = e2e_summary["wall_time_s"]
    rows += overhead_rows + [
        ("libcosim alone: no observer, step(n) between reference changes", lb_wall, f"{lb_wall / lib_wall:.2f}",
         f"load {lb_wall - lb_first - lb_rest:.2f} s, first step (initialises the FMUs) {lb_first:.2f} s, the other "
         f"{steps - 1} steps {lb_rest:.2f} s = {lb_rest / (steps - 1) * 1e6:.0f} us per communication step"),
        ("what-if: libcosim, run_ssp, with the SensorChain's transition cache tolerant of libcosim's step-size "
         "rounding (patched in this process)", patched_wall, f"{patched_wall / lib_wall:.2f}",
         f"ours / this: `causal` {ours_wall['causal'] / patched_wall:.2f}, "
         f"`jacobi` {ours_wall['jacobi'] / patched_wall:.2f}"),
        ("libcosim, run_ssp, in a child process with OPENBLAS_NUM_THREADS=1", blas1, f"{blas1 / lib_wall:.2f}",
         f"ours / this: `causal` {ours_wall['causal'] / blas1:.2f}, `jacobi` {ours_wall['jacobi'] / blas1:.2f} "
         "(ours measured in this process, default BLAS threads)"),
        ("pure-Python loop: simulate_closed_loop (gain-scheduled PID, slow plant, coloured noise; no tracker, no "
         "analog filter)", py_wall, f"{py_wall / lib_wall:.2f}",
         f"loop {py_loop:.2f} s ({py_run.time_s.size} samples), gain design + noise {py_wall - py_loop:.2f} s"),
        ("`nfal run` end to end from an empty build folder (subprocess, once)", e2e_wall, f"{e2e_wall / lib_wall:.2f}",
         f"the run's own wall_time_s {e2e_run:.2f} s; interpreter start, imports, FMU build, plot, metrics "
         f"{e2e_wall - e2e_run:.2f} s"),
    ]
    hosts = []
    for key, t in split.items():
        calls = t["result"].summary["do_step_wall_time_s"] + t["exchange"] if key in ("causal", "jacobi") else None
        hosts.append({"host": key, **{k: t[k] for k in ("wall", "before", "fmu_setup", "loop", "fmu_loop", "after")},
                      "calls": calls})
    result = {"stop_s": stop, "steps": steps, "fmu_steps": fmu_steps, "repeats": args.repeats, "load_at_end": end_load,
              "cases": [{"case": name, "wall_s": seconds, "ratio": ratio, "notes": notes}
                        for name, seconds, ratio, notes in rows], "where_time_goes": hosts}
    print(record.save("cosim", result))
    record.show(tables(result))
    holder.cleanup()



HOST_NAMES = {"causal": "ours, `causal`", "jacobi": "ours, `jacobi`", "libcosim": "libcosim, run_ssp",
              "libcosim_patched": "libcosim, run_ssp, SensorChain cache patched (what-if)",
              "libcosim_bare": "libcosim alone (no observer, step(n))"}


def title(result: dict) -> str:
    return "Co-simulation: the Fig. 7 loop as FMUs, ours against OSP libcosim"


def tables(result: dict) -> list[record.Table]:
    cases = record.Table(f"fig7_slow, {result['stop_s']:g} s simulated at {STEP * 1e3:g} ms ({result['steps']} "
                         f"communication steps x 4 FMUs), best of {result['repeats']}; ratio: wall time / libcosim's "
                         "(run_ssp, the baseline) in this run; goal for ours: <= 1.2:",
                         ["case", "wall time [s]", "ratio", "notes"],
                         [[c["case"], f"{c['wall_s']:.2f}", c["ratio"], c["notes"]] for c in result["cases"]])
    rows = []
    for t in result["where_time_goes"]:
        if t["calls"] is not None:
            layers, host = f"{t['calls'] - t['fmu_loop']:.2f}", t["loop"] - t["calls"]
        else:
            layers, host = "(in host)", t["loop"] - t["fmu_loop"]
        rows.append([HOST_NAMES[t["host"]], f"{t['wall']:.2f}", f"{t['before']:.2f}", f"{t['fmu_setup']:.2f}",
                     f"{t['loop']:.2f}", f"{t['fmu_loop']:.2f}", layers, f"{host:.2f}",
                     f"{host / result['fmu_steps'] * 1e6:.1f}", f"{t['after']:.2f}"])
    split = record.Table("Where the time goes: one more run of each, every FMU call timed in place (adds ~1 us per "
                         "call). \"In the FMUs\": their Python slave methods; \"FMI call layers\": fmpy, ctypes and "
                         "pythonfmu's C wrapper (our call-site time minus the FMUs' own); \"host\": the rest of the "
                         "loop, libcosim's includes its FMI layers.",
                         ["host", "wall [s]", "before the first doStep [s]", "of it in the FMUs [s]", "loop [s]",
                          "in the FMUs [s]", "FMI call layers [s]", "host [s]", "host per FMU step [us]",
                          "after the last doStep [s]"], rows)
    return [cases, split]


if __name__ == "__main__":
    main()
