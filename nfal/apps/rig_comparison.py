"""``nfal compare --port``'s application: each controller of a comparison run on a rig (fig7_hil, paced on the wall
clock, from rest), its run kept, as :class:`~nfal.models.closed_loop.ClosedLoopRun` s a comparison's metrics and
plot take as they take simulated ones."""

from __future__ import annotations

import datetime
from collections.abc import Callable, Mapping
from pathlib import Path

from nfal.apps.build import DEFAULT_BUILD_DIR, build_all
from nfal.apps.fig7 import HARDWARE, REFERENCE, loop_run
from nfal.models.closed_loop import ClosedLoopRun
from nfal.models.reference import Staircase
from nfal.models.comparison import controller_design, controller_name
from nfal.orchestration import run_structure


def controller_on_rig(archive: Path, key: str, reference: Staircase, parameters: Mapping[str, object], *,
                      sample_rate_hz: float, out_dir: Path, realtime: bool = True,
                      overwrite: bool = False) -> ClosedLoopRun:
    """fig7_hil (``archive``) with controller ``key`` (``gs`` or a design height in um: ``controller_design``) and
    ``parameters`` (``proxy.port`` among them) over ``reference``, kept in ``out_dir``: the run as a comparison takes
    it. ``realtime`` False: a rig in lockstep paces the loop."""
    result = run_structure(archive, stop_time=reference.duration_s, step_size=1.0 / sample_rate_hz,
                           inputs={REFERENCE: reference}, parameters={**parameters, **controller_design(key)},
                           realtime=realtime, out_dir=out_dir, overwrite=overwrite, plot=False, progress=False)
    return loop_run(result.table(), controller_name(key), HARDWARE)


def compare_on_rig(keys: list[str], reference: Staircase, parameters: Mapping[str, object], *, sample_rate_hz: float,
                   build_dir: str | Path | None = None, runs_dir: str | Path | None = None,
                   progress: Callable[[], None] = lambda: None) -> tuple[dict[str, ClosedLoopRun], Path]:
    """Each controller of ``keys`` on the rig, one after the other (:func:`controller_on_rig`, paced on the wall
    clock); ``progress()`` after each. Returns key -> run, and the folder with the runs (default
    runs/compare-<date-time>)."""
    archive = build_all(build_dir or DEFAULT_BUILD_DIR, structures=("fig7_hil",))["fig7_hil"]
    folder = Path(runs_dir or Path("runs") / f"compare-{datetime.datetime.now():%Y%m%d-%H%M%S}")
    runs = {}
    for key in keys:
        runs[key] = controller_on_rig(archive, key, reference, parameters, sample_rate_hz=sample_rate_hz,
                                      out_dir=folder / key)
        progress()
    return runs, folder
