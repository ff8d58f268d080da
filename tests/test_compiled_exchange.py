"""The master's step in C (orchestration/exchange_kernel.c): the same calls with the same values as the master's
Python, so every result to the bit, every end of a horizon and every failing call's report the same; where there is
no kernel, the Python exchange and one line saying why."""

from __future__ import annotations

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
