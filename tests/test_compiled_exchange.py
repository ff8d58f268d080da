"""The master's step in C (orchestration/exchange_kernel.c): the same calls with the same values as the master's
Python, so every result to the bit, every end of a horizon and every failing call's report the same; where there is
no kernel, the Python exchange and one line saying why."""

from __future__ import annotations

import ctypes
import logging
from pathlib import Path

import pytest
from helpers.shared_builds import shared_build
from reference_fmus.build import build_reference_fmus, compiler

from nfal.errors import FmuCallError
from nfal.orchestration import compiled_exchange, run_structure

pytestmark = pytest.mark.slow  # FMUs built and run


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    if compiler() is None:
        pytest.fail("the FMI Reference FMUs and the master's kernel need a C compiler: apt-get install gcc")
    return shared_build(tmp_path_factory, "reference_fmus", build_reference_fmus)


def both_ways(monkeypatch, tmp_path: Path, run) -> dict:
    """``run(out_dir)`` with the kernel and with ``NFAL_COMPILED_EXCHANGE=off``: {"C": ..., "Python": ...}."""
    results = {}
    for engine, switch in (("C", "on"), ("Python", "off")):
        monkeypatch.setenv(compiled_exchange.SWITCH, switch)
        compiled_exchange.library.cache_clear()
        results[engine] = run(tmp_path / engine)
    compiled_exchange.library.cache_clear()
    return results


@pytest.mark.parametrize("algorithm", ["causal", "jacobi"])
def test_third_party_fmus_exchange_the_same_to_the_bit(reference, tmp_path, monkeypatch, algorithm):
    """The Reference FMUs' Stair (an Integer, its own horizon ended by fmi2Discard) into Feedthrough, plain and through
    a LinearTransformation: results.csv byte for byte, and the same note of the horizon."""
    runs = both_ways(monkeypatch, tmp_path, lambda out: run_structure(
        reference / "stair_feedthrough.ssd", algorithm=algorithm, out_dir=out, plot=False, progress=False))
    assert {engine: run.summary["exchange_engine"] for engine, run in runs.items()} == {"C": "C", "Python": "Python"}
    assert (tmp_path / "C" / "results.csv").read_bytes() == (tmp_path / "Python" / "results.csv").read_bytes()
    notes = {engine: (run.summary["note"], run.summary["steps_completed"]) for engine, run in runs.items()}
    assert notes["C"] == notes["Python"] and "Stair" in str(notes["C"])


def test_a_failing_call_is_reported_alike(fig7_archives, tmp_path, monkeypatch):
    """A reference the Controller refuses, from t = 20 ms: its computed drive's fmi2GetReal fails in the exchange. The
    same error (element, function, reason) and the same rows before it, either way."""
    def run(out: Path):
        with pytest.raises(FmuCallError) as failure:
            run_structure(fig7_archives["fig7_slow"], stop_time=0.05, step_size=5e-4, out_dir=out, plot=False,
                          progress=False, inputs={"Controller.reference": lambda t: 80e-6 if t < 0.02 else 1.0})
        return str(failure.value)

    errors = both_ways(monkeypatch, tmp_path, run)
    assert errors["C"] == errors["Python"]
    assert "Controller" in errors["C"] and "fmi2GetReal" in errors["C"] and "reference" in errors["C"]
    assert (tmp_path / "C" / "results.csv").read_bytes() == (tmp_path / "Python" / "results.csv").read_bytes()


def test_without_a_compiler_the_master_exchanges_in_python(reference, tmp_path, monkeypatch, caplog):
    """No C compiler (``CC`` a command that fails) and an empty cache: one line says why, and the run is the same."""
    monkeypatch.setenv("NFAL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", "false")
    compiled_exchange.library.cache_clear()
    try:
        with caplog.at_level(logging.INFO, logger="nfal.orchestration.compiled_exchange"):
            result = run_structure(reference / "stair_feedthrough.ssd", out_dir=tmp_path / "run", plot=False,
                                   progress=False)
    finally:
        compiled_exchange.library.cache_clear()
    assert result.summary["exchange_engine"] == "Python" and result.summary["steps_completed"] > 0
    said = [r.message for r in caplog.records if "its C kernel could not be built" in r.message]
    assert len(said) == 1, said


def test_an_integer_external_input_keeps_the_exchange_in_python(reference, tmp_path):
    """A Python int may not fit a double: an Integer external input (Feedthrough's Int32_input, 2^40 + 1, wrapped
    into 32 bits by the set as ctypes wraps it) is exchanged from Python, exactly."""
    result = run_structure(reference / "stair_feedthrough.ssd", out_dir=tmp_path, plot=False, progress=False,
                           stop_time=0.4, inputs={"Feedthrough.Int32_input": 2 ** 40 + 1})
    assert result.summary["exchange_engine"] == "Python"
    assert set(result["Feedthrough.Int32_output"]) == {1}


def _loaded(values, type_, kind=compiled_exchange.LOAD, function=None, fmi=2):
    """One transfer of ``values`` through the kernel on a row holding them: (the buffer, the row) afterwards."""
    n = len(values)
    buffer = (type_ * n)()
    row = (ctypes.c_double * n)(*values)
    columns = (ctypes.c_int32 * n)(*range(n))
    vr = (ctypes.c_uint32 * n)(*range(n))
    entry = compiled_exchange._TransferC(function=function, component=None, vr=ctypes.addressof(vr), n=n, fmi=fmi,
                                         kind=kind, type=compiled_exchange.TYPE_CODES[type_],
                                         buffer=ctypes.addressof(buffer),
                                         columns=ctypes.cast(columns, ctypes.POINTER(ctypes.c_int32)))
    status = ctypes.c_int32()
    assert compiled_exchange.library().nfal_transfers(ctypes.byref(entry), 1, row, ctypes.byref(status)) == -1
    return list(buffer), list(row)


@pytest.mark.parametrize("type_", [ctypes.c_int8, ctypes.c_uint8, ctypes.c_int16, ctypes.c_uint16, ctypes.c_int32,
                                   ctypes.c_uint32, ctypes.c_bool])
def test_an_integer_target_takes_a_value_as_ctypes_does(type_):
    """Out of its range a value wraps modulo 2^bits, as a Python int set into a ctypes integer (a UInt32 output of
    3e9 into an Int32 input); a C cast would be undefined there."""
    values = [0.0, 1.0, -1.0, 127.0, 128.0, 255.0, 256.0, -129.0, 40000.0, -40000.0, 3e9, -3e9, 2.0 ** 40 + 5]
    expected = (type_ * len(values))()
    for j, value in enumerate(values):
        expected[j] = int(value)
    assert _loaded(values, type_)[0] == list(expected)


def test_a_boolean_read_is_0_or_1_whatever_byte_the_fmu_wrote():
    """An FMI 3.0 Boolean whose byte is 2 (a non-conforming FMU) is read as 1, as ctypes reads a c_bool."""
    signature = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p,
                                 ctypes.c_size_t)

    def get_boolean(_instance, _vr, n, values, _n_values):
        ctypes.memmove(values, bytes([2, 0, 1][:n]), n)
        return 0

    function = signature(get_boolean)
    _, row = _loaded([0.0, 0.0, 0.0], ctypes.c_bool, compiled_exchange.GET, ctypes.cast(function, ctypes.c_void_p),
                     fmi=3)
    assert row == [1.0, 0.0, 1.0]
