"""Union-find over the integers ``0`` to ``n - 1`` (connectivity while building and importing road graphs)."""

from __future__ import annotations


class DisjointSet:
    """
    Disjoint sets with path halving; a union keeps the smaller root, so roots are deterministic.

    :param n: Number of elements
    """

    def __init__(self, n: int) -> None:
        self.parent = list(range(n))

    def find(self, x: int) -> int:
        parent = self.parent
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    def union(self, a: int, b: int) -> bool:
        """Join the sets of ``a`` and ``b``; returns whether they were separate."""
        root_a, root_b = self.find(a), self.find(b)
        if root_a == root_b:
            return False
        self.parent[max(root_a, root_b)] = min(root_a, root_b)
        return True
