"""A replay buffer file as large as what the buffer holds, not as its capacity.

SB3's ``save_replay_buffer`` pickles the buffer's arrays whole: a 50,000-transition buffer of CampusNav's
observations is 207 MB on disk after 1,500 steps. :func:`dump_compact_buffer` pickles the same buffer with each array
that has a row per slot cut to the rows stored (the rest is one fill value, kept) and its repeated rows stored once
(CampusNav's observations repeat: a map has a few hundred places); unpickling rebuilds the very same buffer
(:func:`_rebuilt`), so that ``model.load_replay_buffer(path)`` reads the file as SB3 writes it, and every array comes
back bit for bit. Importing this module needs numpy only.
"""

from __future__ import annotations

import copy
import pickle
from typing import IO, Any

import numpy as np

__all__ = ["dump_compact_buffer"]

# Store an array's rows once each only when that takes at most this share of the rows as they are
_DEDUPLICATE_BELOW = 0.5


def _pack(array: np.ndarray, stored: int) -> dict[str, Any] | None:
    """
    An array with a row per buffer slot, as its stored rows (once each, with the index of each) and the fill value of
    the rest; ``None`` where the rest is not one value (kept whole).
    """
    if array.dtype.kind not in "biufc" or array.ndim == 0:
        return None
    tail = array[stored:]
    fill = tail.reshape(-1)[0] if tail.size else np.zeros((), dtype=array.dtype)
    if tail.size and not np.array_equal(tail, np.broadcast_to(fill, tail.shape)):
        return None
    # The row width spelt out: an empty buffer (a run saved before it stored a transition) has no -1 to infer
    head = np.ascontiguousarray(array[:stored]).reshape(stored, int(np.prod(array.shape[1:], dtype=np.int64)))
    packed: dict[str, Any] = {"shape": array.shape, "dtype": array.dtype, "fill": fill, "rows": head, "index": None}
    if stored and head.shape[1]:
        keys = head.view(np.dtype((np.void, head.dtype.itemsize * head.shape[1]))).reshape(-1)
        _, first, index = np.unique(keys, return_index=True, return_inverse=True)
        if first.size * head.shape[1] * head.dtype.itemsize + index.size * 4 <= _DEDUPLICATE_BELOW * head.nbytes:
            packed["rows"], packed["index"] = head[first], index.astype(np.int32).reshape(-1)
    return packed


def _unpack(packed: dict[str, Any]) -> np.ndarray:
    array = np.full(packed["shape"], packed["fill"], dtype=packed["dtype"])
    rows = packed["rows"] if packed["index"] is None else packed["rows"][packed["index"]]
    array[: len(rows)] = rows.reshape(len(rows), *packed["shape"][1:])
    return array


def _rebuilt(shell: Any, packed: dict[str, tuple[str, Any]]) -> Any:
    """The buffer of a compact file: its shell with every packed array (or dict of arrays) put back."""
    for name, (kind, value) in packed.items():
        setattr(shell, name, {key: _unpack(part) for key, part in value.items()} if kind == "dict" else _unpack(value))
    return shell


def _arrays(value: Any) -> list[np.ndarray]:
    """The arrays of an attribute: itself, or the values of a dict of arrays."""
    if isinstance(value, np.ndarray):
        return [value]
    if isinstance(value, dict):
        return [v for v in value.values() if isinstance(v, np.ndarray)]
    return []


class _CompactBuffer:
    """Pickles as a call of :func:`_rebuilt` on the buffer's shell and its packed arrays."""

    def __init__(self, buffer: Any) -> None:
        self.buffer = buffer

    def __reduce__(self) -> tuple[Any, tuple[Any, dict[str, tuple[str, Any]]]]:
        buffer = self.buffer
        slots = int(buffer.buffer_size)
        stored = slots if buffer.full else int(buffer.pos)
        shell = copy.copy(buffer)  # shallow: the live buffer keeps its arrays
        packed: dict[str, tuple[str, Any]] = {}
        for name, value in vars(buffer).items():
            if isinstance(value, np.ndarray) and value.ndim and value.shape[0] == slots:
                part = _pack(value, stored)
                if part is not None:
                    packed[name] = ("array", part)
            elif (
                isinstance(value, dict)
                and value
                and all(isinstance(v, np.ndarray) and v.ndim and v.shape[0] == slots for v in value.values())
            ):
                parts = {key: _pack(v, stored) for key, v in value.items()}
                if all(part is not None for part in parts.values()):
                    packed[name] = ("dict", parts)
        # An array that shares memory with another attribute stays whole: rebuilt apart, they would no longer share
        arrays = [(name, a) for name, value in vars(buffer).items() for a in _arrays(value)]
        for name in list(packed):
            mine = _arrays(getattr(buffer, name))
            if any(o_name != name and np.may_share_memory(a, o) for a in mine for o_name, o in arrays):
                del packed[name]
        for name in packed:
            setattr(shell, name, None)
        return _rebuilt, (shell, packed)


def dump_compact_buffer(buffer: Any, file: IO[bytes]) -> None:
    """
    Pickle an SB3 replay buffer (``buffer_size``, ``pos`` and ``full`` as SB3's buffers have them) to ``file``, its
    arrays cut to what it stores; ``pickle.load`` (and so ``load_replay_buffer``) gives back the same buffer.
    """
    pickle.dump(_CompactBuffer(buffer), file, protocol=pickle.HIGHEST_PROTOCOL)
