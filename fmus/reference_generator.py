"""ReferenceGenerator FMU: the experiment of Figs. 9-10 inside the archive (the height reference, a step sequence).

A thin adapter over :class:`nfal.models.reference.StepSequence`. The Fig. 7 structures connect its
``reference`` output to ``Controller.reference``, so that any host (ecos, libcosim, FMPy) runs the same
experiment as ``nfal run`` (docs/cosimulation.md, "The experiment in the archive"). Parameters, in the
order they take precedence:

* ``table``: rows ``time_s,reference_m`` (newlines, ``;`` or spaces between rows; an optional header), or the
  name of a CSV file in the FMU's ``resources/`` folder (``my_reference.csv``);
* ``times`` [s] with ``levels`` [m]: change times and levels, lists of equal length separated by spaces (or
  commas: but a host that logs string parameters into an unquoted CSV, as ecos does, splits them);
* else the staircase: ``levels`` [m], the first held ``lead`` [s], the others ``hold`` [s]; by default the
  paper's (60-180 um, 0.1 s lead, 0.6 s holds: 3.7 s).

``reference`` at a communication point t is the level of the last change at or before t (held between
changes); the FMU has no inputs and no state besides time.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from nfal.fmus.base import DefaultExperiment, NfalSlave
from nfal.models.reference import Staircase
from nfal.models.plausibility import require_clearances
from nfal.models.reference import StepSequence, numbers

from nfal.errors import InvalidParameterError

_PAPER = Staircase()
#: The staircase's defaults as the FMU declares them (levels as text, space-separated: ``"6e-05 0.0001 ..."``; a
#: host that logs string parameters into an unquoted CSV, as ecos does, would split a comma-separated one).
DEFAULT_LEVELS = " ".join(repr(level) for level in _PAPER.levels_m)
#: The parameters and their defaults.
PARAMETERS = {"levels": DEFAULT_LEVELS, "lead": _PAPER.lead_s, "hold": _PAPER.hold_s, "times": "", "table": ""}


def reference_of(parameters: Mapping[str, object], resources: str | None = None) -> Staircase | StepSequence:
    """The reference the parameters describe (missing ones: their defaults; see the module docstring): a
    :class:`Staircase` when it is one (``levels``, ``lead``, ``hold``), else a :class:`StepSequence`.
    ``resources``: the FMU's resources folder, where a ``table`` file name is looked up."""
    unknown = set(parameters) - set(PARAMETERS)
    if unknown:
        raise InvalidParameterError("ReferenceGenerator parameter", sorted(unknown)[0], f"one of {sorted(PARAMETERS)}")
    reference = _described({**PARAMETERS, **parameters}, resources)
    require_clearances("ReferenceGenerator levels", reference.levels_m)  # 60 for 60 um: named here, not downstream
    return reference


def _described(values: Mapping[str, object], resources: str | None) -> Staircase | StepSequence:
    table = str(values["table"]).strip()
    if table:
        if table.lower().endswith(".csv") and "," not in table:
            return StepSequence.from_table(_resource_text(table, resources), name=table)
        return StepSequence.from_table(table, name="table")
    if str(values["times"]).strip():
        return StepSequence.from_text(str(values["times"]), str(values["levels"]))
    return Staircase(numbers("levels", str(values["levels"])), hold_s=float(values["hold"]),
                     lead_s=float(values["lead"]))


def _resource_text(name: str, resources: str | None) -> str:
    if not resources:
        raise InvalidParameterError("table", name, "a table, or a file name with the FMU's resources folder known")
    folder = Path(resources).resolve()
    path = (folder / name).resolve()
    if folder not in path.parents or not path.is_file():
        raise InvalidParameterError("table", name, f"a CSV file in the FMU's resources folder {folder}")
    return path.read_text(encoding="utf-8")


class ReferenceGenerator(NfalSlave):
    """The height reference of the Fig. 7 loop: a staircase, explicit steps or a table."""

    description = ("Height reference of the Fig. 7 loop: the paper's staircase (Figs. 9-10) by default, "
                   "any staircase, step sequence (times, levels) or time_s,reference_m table")
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=_PAPER.duration_s, step_size=5e-4)

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_output("reference", unit="m", description="height reference h_ref (held between changes)",
                        getter=self._reference)
        self.add_parameter("levels", PARAMETERS["levels"],
                           description="levels of the staircase or of the steps [m], separated by spaces or commas")
        self.add_parameter("lead", _PAPER.lead_s, unit="s", description="staircase: how long the first level is held")
        self.add_parameter("hold", _PAPER.hold_s, unit="s", description="staircase: how long each later level is held")
        self.add_parameter("times", "", description="change times [s], one per level, separated by spaces or commas; "
                           "empty: the staircase of lead and hold")
        self.add_parameter("table", "", description="time_s,reference_m rows (separated by newlines, ';' or spaces) "
                           "or the name of a CSV file in the FMU's resources folder; overrides levels and times")
        self._sequence: StepSequence | None = None

    def sequence(self) -> StepSequence:
        """The step sequence the parameters describe (see the module docstring)."""
        reference = reference_of({name: getattr(self, name) for name in PARAMETERS}, self.resources)
        return reference if isinstance(reference, StepSequence) else StepSequence.from_staircase(reference)

    def _reference(self) -> float:
        if self._sequence is None:
            self._sequence = self.sequence()
        return self._sequence(self.time)

    def setup(self) -> None:
        self._sequence = None
        self._sequence = self.sequence()

    def step(self, current_time: float, step_size: float) -> None:
        pass  # the reference is a function of time alone

    def set_internal_state(self, state: dict) -> None:
        self._sequence = None  # rebuilt from the restored parameters when next read
