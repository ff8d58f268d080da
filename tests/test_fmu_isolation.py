"""Each FMU runs the nfal code and data it carries (fmus/bundle_loader.py), whatever else the host loaded.

Python keeps one module per name in a process. Before the loader, the first nfal FMU a host loaded
served ``nfal`` to every other: SlowPlant then ReynoldsPlant in one FMPy process failed (the second
read its mode-shape file through the first one's folder, which FMPy had deleted), and two builds of
different nfal versions silently ran the first one's code.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
from fmpy import extract

import nfal
from nfal.fmus import build
from helpers.fmu_instance import Instance

HIDE_EDITABLE_INSTALL = textwrap.dedent('''
    import sys
    sys.meta_path[:] = [f for f in sys.meta_path if not getattr(f, "__module__", "").startswith("__editable__")]
    sys.path_hooks[:] = [h for h in sys.path_hooks if not getattr(h, "__module__", "").startswith("__editable__")]
    sys.path_importer_cache.clear()
''')

ONE_AFTER_THE_OTHER = HIDE_EDITABLE_INSTALL + textwrap.dedent('''
    import fmpy
    for fmu in sys.argv[1:]:  # fmpy extracts each FMU to a new folder and deletes it after the run
        result = fmpy.simulate_fmu(fmu, stop_time=0.002, step_size=5e-4, output_interval=5e-4,
                                   start_values={"excitation_amplitude": 5e-6})
        print(fmu.rsplit("/", 1)[-1], len(result), result["height"][-1])
''')


@pytest.mark.slow  # two FMUs built and run
def test_two_different_nfal_fmus_in_one_process(tmp_path_factory, tmp_path):
    """SlowPlant, then ReynoldsPlant (which reads its excitation-form CSV), then SlowPlant again."""
    fmus = build.build_fmus(tmp_path_factory.mktemp("pair"), ["SlowPlant", "ReynoldsPlant"])
    order = [fmus["SlowPlant"], fmus["ReynoldsPlant"], fmus["SlowPlant"]]
    done = subprocess.run([sys.executable, "-c", ONE_AFTER_THE_OTHER, *map(str, order)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:] + done.stdout[-2000:]
    lines = done.stdout.split("\n")[:3]
    assert [line.split()[0] for line in lines] == ["SlowPlant.fmu", "ReynoldsPlant.fmu", "SlowPlant.fmu"]
    for line in lines:
        _, samples, height = line.split()
        assert int(samples) == 5 and 50e-6 < float(height) < 100e-6


AT_ONCE = HIDE_EDITABLE_INSTALL + textwrap.dedent('''
    import threading
    import fmpy
    from fmpy.fmi2 import FMU2Slave
    barrier, failures = threading.Barrier(len(sys.argv) - 1), []

    def instantiate(fmu, md, folder):
        slave = FMU2Slave(guid=md.guid, unzipDirectory=folder, instanceName="x",
                          modelIdentifier=md.coSimulation.modelIdentifier)
        barrier.wait()
        try:
            slave.instantiate()
            slave.freeInstance()
        except Exception as exc:
            failures.append(f"{fmu}: {exc}")

    # read and extracted first, in this thread: lxml parsing in five threads at once once spun for minutes
    # (2026-11-29, in read_model_description), and what is tested here is the instantiation
    loaded = [(fmu, fmpy.read_model_description(fmu), fmpy.extract(fmu)) for fmu in sys.argv[1:]]
    threads = [threading.Thread(target=instantiate, args=args) for args in loaded]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    print(failures or "all instantiated")
''')


@pytest.mark.slow  # three FMUs built and loaded in a process of their own
def test_nfal_fmus_instantiated_at_once_in_threads(tmp_path_factory, tmp_path):
    """A Dask worker's threads each start a run, each run its FMUs in a folder of its own: one import of a slave
    module at a time in the process, and one nfal bundle at a time set aside and imported. Before, a lock of each
    FMU's own let three different FMUs fail in 8 of 8 processes (KeyError 'nfal'), and two instances of one FMU
    deleted each other's module mid-import (KeyError 'nfal_sensor_chain'): 1-2 of 12 runs of every sweep on a new
    two-thread Dask worker failed."""
    fmus = build.build_fmus(tmp_path_factory.mktemp("three"), ["SlowPlant", "Controller", "SensorChain"])
    order = [fmus["SlowPlant"], fmus["SensorChain"], fmus["Controller"], fmus["SensorChain"], fmus["SlowPlant"]]
    for _ in range(2):  # a fresh process each: the first loads race (without the locks, half the processes failed)
        done = subprocess.run([sys.executable, "-c", AT_ONCE, *map(str, order)], cwd=tmp_path,
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0 and done.stdout.strip() == "all instantiated", done.stdout + done.stderr[-3000:]


STAMP_SCRIPT = '''
"""Test slave: its output is the minor version of the nfal package the FMU carries."""
from nfal import __version__
from nfal.fmus.base import NfalSlave


class Stamp(NfalSlave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.add_output("minor", unit="1", description="nfal's minor version", getter=self.minor_version)

    @staticmethod
    def minor_version():
        return float(__version__.split(".")[-1])

    def setup(self):
        pass

    def step(self, current_time, step_size):
        pass
'''


KERNELS_COMPILED = textwrap.dedent('''
    import sys
    import fmpy
    if sys.argv[2] == "own":  # the host's nfal has compiled its own kernels: its numba_cache is in sys.modules
        from nfal.models import numba_cache, slow_kernels
        slow_kernels.load()
    # a run long enough that the SlowPlant compiles its kernels at set-up (fmus/slow_plant.py), inside the FMU
    fmpy.simulate_fmu(sys.argv[1], stop_time=1.0, step_size=5e-4, output_interval=0.1,
                      start_values={"excitation_amplitude": 3e-6})
    (slave_module,) = sys.modules["_nfal_fmu_bundles"].bundles.values()
    kernels = slave_module.FixedStepPlant.__init__.__globals__["slow_kernels"]
    locator = kernels.free_flight._cache._impl.locator
    source = type(locator).get_source_stamp.__code__.co_filename  # the copy that defined the locator
    own = source == kernels.__file__.replace("slow_kernels", "numba_cache")
    hosts = "nfal" in sys.modules and sys.modules["nfal.models.numba_cache"] is numba_cache
    print(type(locator).__name__, own, "nfal" in sys.modules, hosts)
''')


@pytest.mark.slow  # an FMU built and run in a Python of its own
@pytest.mark.parametrize("host, imported", [("none", "False False"), ("own", "True True")])
def test_an_fmu_compiles_its_kernels_with_its_own_copy_and_imports_no_other(tmp_path_factory, tmp_path, host,
                                                                            imported):
    """numba re-imports a kernel's module by name as it loads it (models/jit.py): the FMU's copy of nfal, set aside,
    must serve it, and its own numba_cache (the content-keyed cache), whether the host has no nfal or its own one,
    which stays as it was. When the installed nfal served it, that copy entered the host's process and its cache
    locator passed the FMU's kernels over, so that ecos compiled them anew, into the FMU's temporary folder, in every
    run; with the host's own numba_cache in sys.modules, so did every FMPy run in it."""
    fmu = build.build_fmus(tmp_path_factory.mktemp("kernels"), ["SlowPlant"])["SlowPlant"]
    done = subprocess.run([sys.executable, "-c", KERNELS_COMPILED, str(fmu), host], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split() == ["ContentKeyedCacheLocator", "True", *imported.split()]


@pytest.mark.parametrize("order", [(1, 2), (2, 1)])
def test_two_versions_of_one_fmu_in_one_process(tmp_path_factory, monkeypatch, order):
    """Two builds with different nfal versions, alive side by side: each answers with its own."""
    script = tmp_path_factory.mktemp("stamp") / "stamp.py"
    script.write_text(STAMP_SCRIPT, encoding="utf-8")
    monkeypatch.setitem(build.FMU_SCRIPTS, "Stamp", str(script))
    instances = []
    for minor in order:
        monkeypatch.setattr(nfal, "__version__", f"9.0.{minor}")  # what the build writes into the FMU's nfal
        fmu = build.build_fmu("Stamp", tmp_path_factory.mktemp(f"v{minor}"))
        instance = Instance(fmu, extract(str(fmu)), name=f"v{minor}")
        instance.initialize()
        instances.append(instance)
    for minor, instance in zip(order, instances):
        instance.step(1e-3)
        assert instance.get("minor") == float(minor)
    for instance in instances:
        instance.free()


@pytest.mark.parametrize("module, pip_name", [("scipy", "scipy")])  # python-control: on use, not at set-up
def test_a_missing_host_package_is_one_logged_line_naming_it(tmp_path_factory, monkeypatch, module, pip_name):
    """fmi2Instantiate fails with the package and its pip command in the host's log, not a traceback."""
    fmu = build.build_fmus(tmp_path_factory.mktemp("missing"), ["Controller"])["Controller"]
    monkeypatch.setitem(sys.modules, module, None)  # what Python does for a package that is not installed
    messages = []
    with pytest.raises(Exception, match="Failed to instantiate"):
        Instance(fmu, extract(str(fmu)), messages=messages)
    assert messages == [(3, f"the Controller FMU needs the Python package '{pip_name}' in the Python that runs it "
                            f"({sys.executable}): pip install {pip_name}")]

