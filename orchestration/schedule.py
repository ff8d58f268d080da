"""The order of setting inputs and reading outputs at a communication point (pure graph work, no FMI).

The graph has one node per recorded output ("get Element.y") and one per driven input ("set
Element.u"). Edges: a link's source output -> its target input (the value must be read before it
is set), and an input -> every output of the same element declared to depend on it (direct
feedthrough: the output must be read after the input is set). A topological order of this graph
is a Gauss-Seidel sweep in which every output read at t_k already reflects every input at t_k
(docs/cosimulation.md, "The loop and the step order"). A cycle is an algebraic loop:
:class:`~nfal.errors.AlgebraicLoopError` names its variables.

Consecutive nodes of one element and kind are merged into one :class:`Action` (one fmi2Set/Get
call per type), and among the nodes ready at any time the order prefers to continue with the same
element and kind, then inputs before outputs, then the SSD's element order: fewer, larger calls.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence

from nfal.errors import AlgebraicLoopError


@dataclasses.dataclass(frozen=True)
class Action:
    """Set the inputs or get the outputs ``variables`` of ``element`` (``kind`` "set" or "get")."""

    kind: str
    element: str
    variables: tuple[str, ...]

    def __str__(self) -> str:
        return f"{self.kind} {', '.join(f'{self.element}.{v}' for v in self.variables)}"


Node = tuple[str, str, str]  # (kind, element, variable)


def causal_sweep(elements: Sequence[str], outputs: Mapping[str, Sequence[str]], inputs: Mapping[str, Sequence[str]],
                 links: Iterable[tuple[tuple[str, str], tuple[str, str]]],
                 feedthrough: Mapping[str, Mapping[str, Sequence[str]]]) -> tuple[Action, ...]:
    """The Gauss-Seidel sweep: a causal order of every set and get at one communication point.

    Parameters
    ----------
    elements : sequence of str
        Element names, in the order used to break ties.
    outputs : mapping of element -> output names to read (recorded or linked)
    inputs : mapping of element -> input names to set (linked or externally driven)
    links : iterable of ((source element, output), (target element, input))
    feedthrough : mapping of element -> mapping of output -> the inputs it depends on directly

    Raises
    ------
    AlgebraicLoopError
        The feedthrough graph has a cycle (the error lists its variables in flow order).
    """
    rank = {name: i for i, name in enumerate(elements)}
    nodes: list[Node] = [("set", e, u) for e in elements for u in inputs.get(e, ())]
    nodes += [("get", e, y) for e in elements for y in outputs.get(e, ())]
    present = set(nodes)
    successors: dict[Node, list[Node]] = {n: [] for n in nodes}
    indegree: dict[Node, int] = {n: 0 for n in nodes}

    def edge(a: Node, b: Node) -> None:
        if a in present and b in present:
            successors[a].append(b)
            indegree[b] += 1

    for (source, output), (target, variable) in links:
        edge(("get", source, output), ("set", target, variable))
    for element in elements:
        for output, depends in feedthrough.get(element, {}).items():
            for variable in depends:
                edge(("set", element, variable), ("get", element, output))

    order: list[Node] = []
    ready = [n for n in nodes if indegree[n] == 0]
    last: tuple[str, str] | None = None
    while ready:
        ready.sort(key=lambda n: ((n[0], n[1]) != last, n[0] != "set", rank[n[1]]))
        node = ready.pop(0)
        order.append(node)
        last = (node[0], node[1])
        for successor in successors[node]:
            indegree[successor] -= 1
            if indegree[successor] == 0:
                ready.append(successor)
    if len(order) < len(nodes):
        raise AlgebraicLoopError(_cycle([n for n in nodes if indegree[n] > 0], successors))
    return merge(order)


def merge(order: Sequence[Node]) -> tuple[Action, ...]:
    """Consecutive nodes of the same kind and element as one :class:`Action`."""
    actions: list[Action] = []
    for kind, element, variable in order:
        if actions and actions[-1].kind == kind and actions[-1].element == element:
            actions[-1] = Action(kind, element, actions[-1].variables + (variable,))
        else:
            actions.append(Action(kind, element, (variable,)))
    return tuple(actions)


def _cycle(remaining: list[Node], successors: Mapping[Node, list[Node]]) -> list[str]:
    """One cycle among the nodes Kahn's algorithm could not order, as ``Element.variable`` names."""
    left = set(remaining)
    start = remaining[0]
    # Walk forward inside the unordered set: every such node has an unordered predecessor, so walking
    # backwards never stops; walking forward along nodes that still have unordered successors does.
    predecessors: dict[Node, list[Node]] = {n: [] for n in left}
    for node in left:
        for successor in successors[node]:
            if successor in left:
                predecessors[successor].append(node)
    path, seen, node = [], {}, start
    while node not in seen:
        seen[node] = len(path)
        path.append(node)
        node = predecessors[node][0]
    loop = path[seen[node]:][::-1]
    # Start the report at an output read, in flow order.
    first = next((i for i, n in enumerate(loop) if n[0] == "get"), 0)
    loop = loop[first:] + loop[:first]
    return [f"{element}.{variable}" for _, element, variable in loop]
