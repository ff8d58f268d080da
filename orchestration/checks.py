"""Checks of a completed run's results, and the status they give it (``summary.json``).

A check is ``check(table) -> findings`` (:func:`~.run.run_structure`'s ``checks``), each finding a
:class:`Finding`: a warning or a failure. The status rule:

* "ok", ``warnings`` empty: the run completed and nothing was found;
* "ok" with ``warnings``: the run completed and its results are whole, but something the caller checks for
  did not happen (e.g. a level of the reference never reached); one line each;
* "failed": the run stopped with an error, or it completed and a check failed (e.g. the object never lifted
  off): ``error`` says why. A completed run keeps every row; :func:`~.run.run_structure` raises
  :class:`~nfal.errors.RunCheckError` as it raises any failure.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable

from nfal.errors import RunCheckError

logger = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class Finding:
    """What a check found: one line; a ``failure`` fails the run, anything else is a warning."""

    message: str
    failure: bool = False


def judge(summary: dict, findings: Iterable[Finding]) -> RunCheckError | None:
    """Put ``findings`` into ``summary`` by the status rule; the error to raise if one is a failure."""
    findings = list(findings)
    summary["warnings"] = [f.message for f in findings if not f.failure]
    for message in summary["warnings"]:
        logger.info("warning: %s", message)  # the command line prints them from the summary
    failures = [f.message for f in findings if f.failure]
    if not failures:
        return None
    summary.update(status="failed", error="; ".join(failures))
    return RunCheckError(summary["error"])
