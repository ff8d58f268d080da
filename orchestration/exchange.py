"""The master's two exchange algorithms (docs/cosimulation.md, "The loop and the step order"), one class each.

An exchange decides, for a :class:`~nfal.orchestration.master.Master`, which values move when: its plan of set and get
actions, what happens in initialisation, before the FMUs step and after. The master owns the FMUs, the row of values
and the transfers that carry the plan out (``sweep``, ``sets``, ``gets``, ``run``, ``load_sets``).
"""

from __future__ import annotations

import logging

from nfal.errors import AlgebraicLoopError

from .compiled_exchange import GET, LOAD, LOAD_AND_SET, SET
from .schedule import Action, causal_sweep

logger = logging.getLogger(__name__)


class CausalExchange:
    """At each communication point, set inputs and read outputs in the causal order of the feedthrough graph
    (:func:`~nfal.orchestration.schedule.causal_sweep`), so a value set now is seen by every FMU downstream of it
    at once: an algebraic loop is refused."""

    name = "causal"
    immediate = True  # a set takes its value from the row as the sweep reaches it

    def plan(self, names, outputs, inputs, links, feedthrough) -> tuple[Action, ...]:
        return causal_sweep(names, outputs, inputs, links, feedthrough)

    def order(self, plan) -> list[str]:
        return ["doStep all from t_k", *(f"{action} (at t_k+1)" for action in plan)]

    def initialise(self, master) -> None:
        """In initialisation mode, the external inputs at t0 set: propagate once."""
        master.run(master.sweep)

    def before_steps(self, master) -> None:
        pass

    def exchange(self, master) -> None:
        """After the FMUs stepped (or left initialisation): the whole sweep at the new time."""
        master.run(master.sweep)

    refresh = exchange

    def programs(self, master) -> tuple[list, list]:
        """What :meth:`before_steps` and :meth:`exchange` do, as the compiled step's transfers and kinds."""
        return [], [(t, GET if t.kind == "get" else LOAD_AND_SET) for t in master.sweep]


class JacobiExchange:
    """OSP libcosim's fixed-step algorithm: set every input from the last exchange, step every FMU, read every output;
    a connection delays by one step, so an algebraic loop is broken (and logged)."""

    name = "jacobi"
    immediate = False  # a set takes the value loaded at the last exchange

    def plan(self, names, outputs, inputs, links, feedthrough) -> tuple[Action, ...]:
        try:
            causal_sweep(names, outputs, inputs, links, feedthrough)
        except AlgebraicLoopError as exc:
            logger.info("algebraic loop %s: broken by jacobi's one-step delay", " -> ".join(exc.variables))
        return tuple(a for e in names for a in (Action("set", e, tuple(inputs[e])),
                                                Action("get", e, tuple(outputs[e]))) if a.variables)

    def order(self, plan) -> list[str]:
        sets = [str(a) for a in plan if a.kind == "set"]
        gets = [str(a) for a in plan if a.kind == "get"]
        return [*sets, "doStep all from t_k", *(f"{g} (at t_k+1, moved to the inputs)" for g in gets)]

    def initialise(self, master) -> None:
        """As libcosim (``fixed_step_algorithm::initialize``): as many rounds of (set the loaded inputs, get every
        output, load them) as there are FMUs."""
        for round_ in range(max(1, len(master.slaves))):
            if round_:
                master.run(master.sets)
            master.run(master.gets)
            master.load_sets()

    def before_steps(self, master) -> None:
        master.run(master.sets)

    def exchange(self, master) -> None:
        master.run(master.gets)
        master.load_sets()

    def refresh(self, master) -> None:
        """An external input changed without time passing: load it for the next step's sets."""
        master.load_sets()

    def programs(self, master) -> tuple[list, list]:
        """What :meth:`before_steps` and :meth:`exchange` do, as the compiled step's transfers and kinds."""
        return [(t, SET) for t in master.sets], [*((t, GET) for t in master.gets), *((t, LOAD) for t in master.sets)]


#: Algorithm name -> its exchange.
EXCHANGES = {exchange.name: exchange for exchange in (CausalExchange, JacobiExchange)}
