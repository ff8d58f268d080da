"""Probe FMUs: test slaves that report what their process or host gave them, built as nfal's own FMUs are."""

from __future__ import annotations

from pathlib import Path

import pytest

from nfal.fmus import build

#: Model name -> its slave script (the class is named as the model).
SCRIPTS = {"BlasProbe": "blas_probe.py", "ThreadStateProbe": "thread_state_probe.py", "TimesProbe": "times_probe.py"}


def build_probe(name: str, out_dir: Path, monkeypatch: pytest.MonkeyPatch, fmi_version: int = 2) -> Path:
    """The probe FMU ``name`` built into ``out_dir``/fmi<version>/ (nfal's build, told of the script for this test)."""
    monkeypatch.setitem(build.FMU_SCRIPTS, name, str(Path(__file__).with_name(SCRIPTS[name])))
    return build.build_fmu(name, Path(out_dir) / f"fmi{fmi_version}", fmi_version=fmi_version)
