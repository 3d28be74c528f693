"""An interned observation array: each distinct row stored once, slots holding row indices.

An env whose observations repeat (a finite set of views, a goal carried in every step) fills a replay buffer with
copies of the same vectors: SB3 stores each one twice per transition (``observations`` and ``next_observations``).
:class:`ObservationTable` stands in for one such array, shape ``(buffer_size, n_envs, *row_shape)``: its slots hold
``int32`` indices into a table of distinct rows, interned by a digest of their bytes, and reading gathers the rows.
One table serves a Dict key's observations and next observations alike (the next observation of step ``t`` is the
observation of step ``t + 1``: one row). Rows are reference-counted by the slots that hold them, and a row no slot
holds any more is reused, so the table never holds more rows than the live distinct ones (its memory is bounded by
the buffer's even where observations never repeat); it grows geometrically.

It supports the indexing SB3's buffers use: ``table[pos] = rows``, ``table[batch_inds, env_inds]`` (and with a
trailing ``:``), ``table[rows, envs] = row``, slices, ``shape``/``dtype``/``nbytes``, ``np.asarray`` and pickling.
Reads return new arrays (never views of the table).
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np

__all__ = ["InternedRows", "ObservationTable"]

_SLOT_DIMS = 2  # (buffer_size, n_envs)


def _row_digest(row: np.ndarray) -> bytes:
    return hashlib.blake2b(row.tobytes(), digest_size=16).digest()


class InternedRows:
    """
    The distinct rows of one or more :class:`ObservationTable`, each stored once and counted by the slots holding it.

    :param row_shape: The shape of a row
    :param dtype: The rows' dtype
    :param capacity: Rows reserved at first (doubled when full)
    """

    def __init__(self, row_shape: tuple[int, ...], dtype: Any, capacity: int = 16) -> None:
        self.row_shape = tuple(int(n) for n in row_shape)
        self.dtype = np.dtype(dtype)
        capacity = max(int(capacity), 2)
        self.rows = np.zeros((capacity, *self.row_shape), dtype=self.dtype)
        self.refs = np.zeros(capacity, dtype=np.int64)
        zero = _row_digest(self.rows[0])  # row 0: the zero row, where every slot starts (as np.zeros reads)
        self._row_of: dict[bytes, int] = {zero: 0}
        self._digest_of: list[bytes | None] = [zero] + [None] * (capacity - 1)
        self._free: list[int] = list(range(capacity - 1, 0, -1))  # a stack: low rows first

    @property
    def n_rows(self) -> int:
        """Distinct rows held by at least one slot."""
        return int(np.count_nonzero(self.refs))

    @property
    def nbytes(self) -> int:
        """Bytes of the rows reserved, with their reference counts."""
        return int(self.rows.nbytes + self.refs.nbytes)

    def hold(self, row: np.ndarray) -> int:
        """
        Count one more slot holding ``row``, stored if new.

        :param row: A row, shape ``row_shape``
        :return: its index
        """
        index = self._intern_one(row)
        self.refs[index] += 1
        return index

    def drop(self, index: int) -> None:
        """Count one slot fewer holding row ``index``; a row no slot holds is freed for reuse."""
        self.refs[index] -= 1
        if self.refs[index] == 0:
            self._release(index)

    def _intern_one(self, row: np.ndarray) -> int:
        digest = _row_digest(np.ascontiguousarray(row))
        found = self._row_of.get(digest)
        if found is not None:
            return found
        if not self._free:
            self._grow()
        index = self._free.pop()
        self.rows[index] = row
        self._row_of[digest] = index
        self._digest_of[index] = digest
        return index

    def _release(self, index: int) -> None:
        digest = self._digest_of[index]
        assert digest is not None
        del self._row_of[digest]
        self._digest_of[index] = None
        self._free.append(index)

    def _grow(self) -> None:
        capacity = len(self.rows)
        self.rows = np.concatenate([self.rows, np.zeros_like(self.rows)])
        self.refs = np.concatenate([self.refs, np.zeros_like(self.refs)])
        self._digest_of += [None] * capacity
        self._free += list(range(2 * capacity - 1, capacity - 1, -1))


class ObservationTable:
    """
    A ``(buffer_size, n_envs, *row_shape)`` array that stores each distinct row once (see the module docstring).

    :param shape: The array's shape: two slot dimensions, then the row's
    :param dtype: The rows' dtype
    :param rows: The distinct rows to share with other tables (e.g. a key's observations and next observations);
        by default its own
    """

    def __init__(self, shape: tuple[int, ...], dtype: Any, rows: InternedRows | None = None) -> None:
        if len(shape) < _SLOT_DIMS:
            raise ValueError(f"ObservationTable needs (buffer_size, n_envs, *row_shape), got shape {shape}")
        self.slot_shape = tuple(int(n) for n in shape[:_SLOT_DIMS])
        self.rows = rows if rows is not None else InternedRows(shape[_SLOT_DIMS:], dtype)
        if self.rows.row_shape != tuple(shape[_SLOT_DIMS:]) or self.rows.dtype != np.dtype(dtype):
            raise ValueError(
                f"shared rows of shape {self.rows.row_shape} and dtype {self.rows.dtype} cannot serve a table of "
                f"shape {shape} and dtype {np.dtype(dtype)}"
            )
        self.ids = np.zeros(self.slot_shape, dtype=np.int32)  # every slot on row 0, the zero row
        self.rows.refs[0] += self.ids.size

    # ------------------------------------------------------------------ ndarray-like attributes
    @property
    def row_shape(self) -> tuple[int, ...]:
        return self.rows.row_shape

    @property
    def dtype(self) -> np.dtype:
        return self.rows.dtype

    @property
    def shape(self) -> tuple[int, ...]:
        return (*self.slot_shape, *self.row_shape)

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def index_nbytes(self) -> int:
        """Bytes of the slots' row indices (what the table costs per transition)."""
        return int(self.ids.nbytes)

    @property
    def nbytes(self) -> int:
        """Bytes of the row indices and of the distinct rows (shared rows counted by every table sharing them)."""
        return self.index_nbytes + self.rows.nbytes

    def __len__(self) -> int:
        return self.slot_shape[0]

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        array = np.take(self.rows.rows, self.ids, axis=0)
        return array if dtype is None else array.astype(dtype)

    def __repr__(self) -> str:
        return f"ObservationTable(shape={self.shape}, dtype={self.dtype}, distinct rows={self.rows.n_rows})"

    # ------------------------------------------------------------------ reading and writing
    def __getitem__(self, key: Any) -> np.ndarray:
        slot_key, row_key = _split(key)
        ids = self.ids[slot_key]
        values = np.take(self.rows.rows, ids, axis=0)  # a copy, shape ids.shape + row_shape
        if row_key:
            values = values[(slice(None),) * np.ndim(ids) + row_key]
        return values

    def __setitem__(self, key: Any, value: Any) -> None:
        slot_key, row_key = _split(key)
        if row_key:
            raise IndexError("ObservationTable writes whole rows: index the slots only (e.g. table[pos] = rows)")
        slots = self._flat_slots(slot_key)
        values, shape = np.asarray(value, dtype=self.dtype), (*slots.shape, *self.row_shape)
        if values.shape != shape:
            values = np.broadcast_to(values, shape)
        flat_ids = self.ids.reshape(-1)
        # One slot after the other, as numpy writes (a slot indexed twice keeps the last row)
        for slot, row in zip(slots.reshape(-1).tolist(), values.reshape(-1, *self.row_shape), strict=True):
            old = int(flat_ids[slot])
            flat_ids[slot] = self.rows.hold(row)  # before dropping: a slot rewritten with its own row keeps it
            self.rows.drop(old)

    def _flat_slots(self, slot_key: Any) -> np.ndarray:
        """The flat slot numbers a slot index selects, in the index's shape."""
        n_envs = self.slot_shape[1]
        if isinstance(slot_key, (int, np.integer)):
            start = (int(slot_key) % self.slot_shape[0]) * n_envs
            return np.arange(start, start + n_envs)
        if isinstance(slot_key, tuple) and len(slot_key) == _SLOT_DIMS and all(map(_is_integer_index, slot_key)):
            rows, envs = np.broadcast_arrays(*(np.asarray(k) for k in slot_key))
            return np.ravel_multi_index((rows, envs), self.slot_shape, mode="wrap")
        # Any other index (slices, masks): the slot numbers through zero-copy broadcast views
        rows = np.broadcast_to(np.arange(self.slot_shape[0])[:, None], self.slot_shape)[slot_key]
        envs = np.broadcast_to(np.arange(n_envs)[None, :], self.slot_shape)[slot_key]
        return np.asarray(rows) * n_envs + np.asarray(envs)


def _is_integer_index(key: Any) -> bool:
    return isinstance(key, (int, np.integer)) or (isinstance(key, np.ndarray) and key.dtype.kind in "iu")


def _split(key: Any) -> tuple[Any, tuple]:
    """Split an index into the slots' part and the rows' part (trailing ``:`` dropped)."""
    if not isinstance(key, tuple) or len(key) <= _SLOT_DIMS:
        return key, ()
    row_key = key[_SLOT_DIMS:]
    while row_key and isinstance(row_key[-1], slice) and row_key[-1] == slice(None):
        row_key = row_key[:-1]
    return key[:_SLOT_DIMS], row_key
