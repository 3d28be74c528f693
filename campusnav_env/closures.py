"""Closure schedules: which roads close (or reopen) when during training, checked before training starts.

A schedule is a list of :class:`ClosureEvent`. Each event fires once, when training has run ``at`` episodes (or env
steps, ``unit="step"``) counted from the start of training with the schedule, and does one of:

- ``close``: close the given roads, e.g. ``[(81, 82)]``;
- ``close_random``: close ``k`` random open roads at once (the paper: 11 around episode 8000), drawn with ``seed`` so
  that they keep every goal reachable;
- ``close_on_route``: close the next road on the agent's *current* greedy route: the road used by most greedy routes
  from every start (``"busiest"``), or the first closable road on the route from one start node (the paper's Fig. 7b
  and 9, one at a time);
- ``reopen``: reopen the given roads, or ``"all"``.

Goals always stay reachable: an explicit closure that would cut a goal off is an error *before* training
(:meth:`ClosureSchedule.validate`), as is an unknown road or a random draw that cannot be met; a road chosen on the
route at run time that cannot be closed is skipped and reported, never silently.

In YAML (``campusnav train --closures schedule.yml``)::

    closures:
      - {at: 2000, close: [[81, 82]]}
      - {at: 4000, close_on_route: busiest}
      - {at: 6000, reopen: all}
      - {at: 8000, close_random: 11, seed: 0}
      - {at: 30000, unit: step, close_on_route: 17}
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from campusnav_env.maps.navigation import NavigationGraph, RoadClosureError
from campusnav_env.maps.refusals import Refusal
from campusnav_env.maps.road_graph import road_key

__all__ = [
    "ClosureEvent",
    "ClosureSchedule",
    "apply_fixed_event",
    "busiest_road",
    "first_road_on_route",
    "road_usage",
]

Road = tuple[int, int]
_EVENT_KEYS = {"at", "unit", "close", "close_random", "seed", "close_on_route", "reopen"}


@dataclass(frozen=True)
class ClosureEvent:
    """
    One scheduled change of the road network (exactly one of the four actions).

    :param at: When it fires: after this many training episodes (or env steps), counted from the start of training
    :param unit: ``"episode"`` or ``"step"``
    :param close: Roads to close
    :param close_random: Number of random open roads to close at once
    :param seed: Seed of the random draw (``close_random``)
    :param close_on_route: ``"busiest"`` (the road most used by the current greedy routes from every start) or a
        start node (the first closable road on the greedy route from it)
    :param reopen: Roads to reopen, or ``"all"``
    """

    at: int
    unit: Literal["episode", "step"] = "episode"
    close: tuple[Road, ...] = ()
    close_random: int = 0
    seed: int = 0
    close_on_route: str | int | None = None
    reopen: tuple[Road, ...] | Literal["all"] = ()

    def __post_init__(self) -> None:
        if isinstance(self.at, bool) or not isinstance(self.at, (int, np.integer)) or self.at < 0:
            raise ValueError(f"closure event: 'at' must be a non-negative int, got {self.at!r}")
        if self.unit not in ("episode", "step"):
            raise ValueError(f"closure event at {self.at}: unit must be 'episode' or 'step', got {self.unit!r}")
        object.__setattr__(self, "close", tuple(_road(r, self) for r in self.close))
        if self.reopen != "all":
            object.__setattr__(self, "reopen", tuple(_road(r, self) for r in self.reopen))
        actions = [bool(self.close), self.close_random > 0, self.close_on_route is not None, bool(self.reopen)]
        if sum(actions) != 1:
            raise ValueError(
                f"closure event at {self.unit} {self.at}: give exactly one of close, close_random, close_on_route, "
                f"reopen (got {sum(actions)})"
            )
        if self.close_random < 0:
            raise ValueError(f"closure event at {self.unit} {self.at}: close_random must be >= 0")
        route = self.close_on_route
        if route is not None and route != "busiest" and (isinstance(route, bool) or not isinstance(route, int)):
            raise ValueError(
                f"closure event at {self.unit} {self.at}: close_on_route must be 'busiest' or a start node, "
                f"got {route!r}"
            )

    def describe(self) -> str:
        """A short human-readable description, e.g. ``"episode 2000: close 81-82"``."""
        if self.close:
            what = "close " + ", ".join(f"{u}-{v}" for u, v in self.close)
        elif self.close_random:
            what = f"close {self.close_random} random roads (seed {self.seed})"
        elif self.close_on_route is not None:
            what = f"close the next road on the route ({self.close_on_route})"
        else:
            what = "reopen all" if self.reopen == "all" else "reopen " + ", ".join(f"{u}-{v}" for u, v in self.reopen)
        return f"{self.unit} {self.at}: {what}"


def _road(value: Any, event: ClosureEvent) -> Road:
    try:
        u, v = (int(x) for x in value)
    except (TypeError, ValueError):
        raise ValueError(
            f"closure event at {event.unit} {event.at}: a road is a pair of node ids, got {value!r}"
        ) from None
    return road_key(u, v)


@dataclass
class ClosureSchedule:
    """
    An ordered list of closure events (sorted by when they fire; steps and episodes may be mixed).

    :param events: The events
    """

    events: list[ClosureEvent] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.events = [e if isinstance(e, ClosureEvent) else ClosureEvent(**e) for e in self.events]

    @classmethod
    def from_dict(
        cls, document: Mapping[str, Any] | Sequence[Mapping[str, Any]], source: str = "schedule"
    ) -> ClosureSchedule:
        """
        Read a schedule from a ``{"closures": [...]}`` mapping (or the bare list), e.g. loaded from YAML.

        :param source: Name of the document for error messages (e.g. the file name)
        :raises ValueError: naming the source, the entry and the key that is wrong
        """
        entries = document.get("closures") if isinstance(document, Mapping) else document
        if not isinstance(entries, list):
            raise ValueError(f"{source}: expected a list under the key 'closures', got {type(entries).__name__}")
        events = []
        for i, entry in enumerate(entries):
            if not isinstance(entry, Mapping):
                raise ValueError(f"{source}: closures[{i}] must be a mapping, got {entry!r}")
            unknown = set(entry) - _EVENT_KEYS
            if unknown:
                raise ValueError(
                    f"{source}: closures[{i}] has unknown key(s) {sorted(unknown)}; allowed: {sorted(_EVENT_KEYS)}"
                )
            if "at" not in entry:
                raise ValueError(f"{source}: closures[{i}] needs the key 'at'")
            try:
                events.append(ClosureEvent(**entry))
            except (TypeError, ValueError) as error:
                raise ValueError(f"{source}: closures[{i}]: {error}") from None
        return cls(events)

    @classmethod
    def from_yaml(cls, path: str | Path) -> ClosureSchedule:
        """Read a schedule from a YAML file (see the module docstring for the format)."""
        import yaml

        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"closure schedule not found: {path}")
        with open(path) as file:
            try:
                document = yaml.safe_load(file)
            except yaml.YAMLError as error:
                raise ValueError(f"{path}: not valid YAML ({error})") from None
        return cls.from_dict(document or {}, source=str(path))

    def validate(self, graph: NavigationGraph, protect: Iterable[int]) -> None:
        """
        Check the schedule against a map before training: every road exists, explicit and random closures keep the
        protected nodes (the goals) reachable, reopenings reopen closed roads.

        Works on a copy: ``graph`` is not changed. Route closures depend on the policy and are checked when they fire
        (only their start node is checked here).

        :raises NoSuchRoadError: (a ``KeyError``) an unknown road, naming the event
        :raises RoadClosureError: a closure that would cut a goal off, naming the event
        :raises RoadStateError: a road closed twice or a reopening of an open road, naming the event
        :raises ValueError: a random draw that cannot be met, a bad start node
        """
        trial = graph.copy()
        protect = list(protect)
        for event in self.ordered():
            try:
                apply_fixed_event(trial, event, protect)
                if isinstance(event.close_on_route, int) and not isinstance(event.close_on_route, bool):
                    trial.map.check_node(event.close_on_route, "close_on_route start")
            except Refusal as error:  # the road refused (not on the map, would cut a goal off, closed already)
                raise error.within(f"closure schedule, {event.describe()}") from None
            except KeyError as error:
                raise KeyError(f"closure schedule, {event.describe()}: {error.args[0]}") from None
            except ValueError as error:
                raise ValueError(f"closure schedule, {event.describe()}: {error}") from None

    def ordered(self) -> list[ClosureEvent]:
        """The events in the order they fire; a schedule that mixes steps and episodes keeps the order it lists."""
        if len({e.unit for e in self.events}) > 1:
            return list(self.events)
        return sorted(self.events, key=lambda e: e.at)


def apply_fixed_event(
    graph: NavigationGraph, event: ClosureEvent, protect: Sequence[int]
) -> tuple[list[Road], list[Road]]:
    """
    Apply an event that does not depend on the policy (close, close_random, reopen) to ``graph``.

    :return: ``(closed, reopened)`` roads
    :raises KeyError, RoadClosureError, ValueError: as :meth:`NavigationGraph.close_road` and ``reopen_road``
    """
    closed: list[Road] = []
    reopened: list[Road] = []
    if event.close:
        for road in event.close:
            graph.close_road(*road, protect=protect)
            closed.append(road)
    elif event.close_random:
        roads = graph.sample_closures(event.close_random, np.random.default_rng(event.seed), protect=protect)
        for road in roads:
            graph.close_road(*road, protect=protect)
            closed.append(road)
    elif event.reopen:
        roads = sorted(graph.closed_roads) if event.reopen == "all" else list(event.reopen)
        for road in roads:
            graph.reopen_road(*road)
            reopened.append(road)
    return closed, reopened


# ------------------------------------------------------------------------------------------------ roads on routes
def road_usage(routes: Iterable[Sequence[int]]) -> Counter[Road]:
    """How many of the given routes (node sequences) travel each road."""
    usage: Counter[Road] = Counter()
    for nodes in routes:
        usage.update({road_key(u, v) for u, v in itertools.pairwise(nodes) if u != v})
    return usage


def _closable(graph: NavigationGraph, road: Road, protect: Sequence[int]) -> bool:
    if graph.is_closed(*road):
        return False
    try:
        graph.close_road(*road, protect=protect)
    except RoadClosureError:
        return False
    graph.reopen_road(*road)
    return True


def busiest_road(graph: NavigationGraph, routes: Iterable[Sequence[int]], protect: Sequence[int]) -> Road | None:
    """The road used by the most routes whose closure keeps the protected nodes reachable (``None`` if none)."""
    for road, _ in sorted(road_usage(routes).items(), key=lambda item: (-item[1], item[0])):
        if _closable(graph, road, protect):
            return road
    return None


def first_road_on_route(graph: NavigationGraph, route: Sequence[int], protect: Sequence[int]) -> Road | None:
    """The first road along ``route`` (a node sequence) that can be closed keeping the protected nodes reachable."""
    for u, v in itertools.pairwise(route):
        if u != v and _closable(graph, road_key(u, v), protect):
            return road_key(u, v)
    return None
