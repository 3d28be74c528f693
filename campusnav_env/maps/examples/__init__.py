"""
Example inputs shipped with the package, for the commands of docs/guide/command_line.md and quick tries:

- ``small_town.graphml``: a road network of 15 intersections and 19 roads over 670 m x 470 m, as osmnx saves one
  (a ``MultiDiGraph``, two-way streets as two edges, a bent road as a WKT ``geometry``, street names), in UTM zone 17N
  metres (``crs`` EPSG:32617); landmarks *Library*, *Town hall*, *Station* and *Market*.
- ``closures.yml``: a closure schedule for it (:mod:`campusnav_env.closures` format): a road beside the Library
  closes after 2,000 env steps, the busiest road of the learned routes after 4,000.

Example::

    from campusnav_env.maps.examples import example_path
    env = gym.make("CampusNav-v0", world=example_path("small_town.graphml"), goals="Library")
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["EXAMPLES", "example_path"]

EXAMPLES = ("small_town.graphml", "closures.yml")


def example_path(name: str) -> Path:
    """
    The path of a shipped example file.

    :param name: One of :data:`EXAMPLES`
    :return: Its path inside the installed package
    :raises FileNotFoundError: if there is no such example, naming the ones there are
    """
    if name not in EXAMPLES:
        raise FileNotFoundError(f"no example named {name!r}; the examples are {', '.join(EXAMPLES)}")
    return Path(__file__).with_name(name)
