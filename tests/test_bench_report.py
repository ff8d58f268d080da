"""docs/benchmarks.md is what the benches' result files give (bench/report.py): no number in it copied by hand."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # imports every bench that wrote a result (nfal, fmpy, libcosimpy): a few seconds
def test_the_benchmarks_document_is_what_the_result_files_give():
    done = subprocess.run([sys.executable, "bench/report.py", "--check"], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
