"""An inter-process lock file for the builders of a cache file, safe against crashed owners.

The builder holds ``<file>.lock``, created with ``O_CREAT | O_EXCL`` (atomic on every OS and on NFS v3+) and recording
the owner's pid, host name and a random token. Others warn that they wait, poll with back-off, and take the lock once
it is released. A lock whose owner no longer runs on this host (a crashed or killed process) is stale: the next process
removes it, under a short-lived guard file so that two waiters cannot remove a fresh lock between them, with a warning.
Owners on other hosts cannot be checked, so waiting ends after a timeout with a :class:`TimeoutError` that names the
lock file and says how to proceed. Release removes the lock only while it still holds the owner's token.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import socket
import sys
import time
import uuid
import warnings
from pathlib import Path

__all__ = ["LockOwner", "acquire_lock", "release_lock"]

# Polling starts fast (short builds, tests) and backs off to one check a second (a stat and a tiny read).
_POLL_FIRST = 0.02
_POLL_MAX = 1.0
# An owner writes its record and a breaker removes a stale lock within milliseconds: a lock file without a readable
# record, or a break guard, older than this was left by a process that died in between.
_ORPHAN_AGE = 10.0


@dataclasses.dataclass(frozen=True)
class LockOwner:
    """The record in a lock file: who builds the cache."""

    pid: int
    host: str
    token: str
    since: float

    @classmethod
    def me(cls) -> LockOwner:
        return cls(pid=os.getpid(), host=socket.gethostname(), token=uuid.uuid4().hex, since=time.time())

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    def __str__(self) -> str:
        started = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.since))
        return f"pid {self.pid} on host {self.host!r} since {started}"


def _read_owner(lock: Path) -> LockOwner | None:
    """
    Read a lock file's record.

    :param lock: The lock file
    :return: Its owner, or None if the record is unreadable (being written, or garbage)
    :raises FileNotFoundError: if the lock file does not exist (it was released)
    """
    try:
        data = lock.read_bytes()
    except PermissionError:  # Windows: the owner is deleting it right now
        return None
    try:
        record = json.loads(data)
        return LockOwner(
            pid=int(record["pid"]), host=str(record["host"]), token=str(record["token"]), since=float(record["since"])
        )
    except (ValueError, KeyError, TypeError):  # JSON and Unicode errors are ValueErrors
        return None


def _unlink(path: Path) -> None:
    """Delete ``path`` if it exists, retrying briefly: Windows refuses while another process has it open."""
    for attempt in range(50):
        try:
            path.unlink(missing_ok=True)
            return
        except PermissionError:
            if attempt == 49:
                raise
            time.sleep(0.01)


def _pid_alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine; errs towards True, as a live owner must never lose its lock."""
    if pid <= 0:
        return False
    if sys.platform == "win32":
        import ctypes
        from ctypes import wintypes

        # os.kill(pid, 0) would terminate the process on Windows: ask for its exit code instead.
        kernel32 = ctypes.WinDLL("kernel32", use_last_error=True)
        kernel32.OpenProcess.argtypes = (wintypes.DWORD, wintypes.BOOL, wintypes.DWORD)
        kernel32.OpenProcess.restype = wintypes.HANDLE
        kernel32.GetExitCodeProcess.argtypes = (wintypes.HANDLE, ctypes.POINTER(wintypes.DWORD))
        kernel32.CloseHandle.argtypes = (wintypes.HANDLE,)
        handle = kernel32.OpenProcess(0x1000, False, pid)  # PROCESS_QUERY_LIMITED_INFORMATION
        if not handle:
            return ctypes.get_last_error() == 5  # ERROR_ACCESS_DENIED: it exists; otherwise there is no such process
        try:
            code = wintypes.DWORD()
            if not kernel32.GetExitCodeProcess(handle, ctypes.byref(code)):
                return True
            return code.value == 259  # STILL_ACTIVE
        finally:
            kernel32.CloseHandle(handle)
    try:
        os.kill(pid, 0)  # signal 0 only checks that the process exists
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: it exists but belongs to another user
        return True
    return True


def _stale_reason(lock: Path, owner: LockOwner | None) -> str | None:
    """Say why the lock was left by a process that died, or return None if its owner may still be building."""
    if owner is None:
        with contextlib.suppress(OSError):
            age = time.time() - lock.stat().st_mtime
            if age > _ORPHAN_AGE:
                return f"it holds no readable owner record and is {age:.0f} s old"
        return None
    if owner.host == socket.gethostname() and not _pid_alive(owner.pid):
        return f"its owner, {owner}, no longer runs"
    return None


def _remove_if_stale(lock: Path) -> str | None:
    """
    Remove a stale lock, guarded so that two waiters judging it stale at once cannot remove a fresh lock between them.

    :param lock: The lock file
    :return: Why the removed lock was stale, or None if nothing was removed (the lock is live, or another process is
        removing it)
    """
    guard = lock.with_name(lock.name + ".break")
    try:
        fd = os.open(guard, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        with contextlib.suppress(OSError):
            if time.time() - guard.stat().st_mtime > _ORPHAN_AGE:
                _unlink(guard)  # its owner died while removing a stale lock
        return None
    os.close(fd)
    try:
        # Judge again while holding the guard: the lock may have been removed and re-created by a live process.
        try:
            reason = _stale_reason(lock, _read_owner(lock))
        except FileNotFoundError:
            return None
        if reason is not None:
            _unlink(lock)
        return reason
    finally:
        _unlink(guard)


def _try_create(lock: Path, owner: LockOwner) -> bool:
    """Create the lock file with ``owner``'s record if there is none; return whether this process now holds it."""
    try:
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        return False
    except PermissionError:
        if sys.platform == "win32":  # the previous owner's lock is still being deleted
            return False
        raise
    try:
        try:
            os.write(fd, owner.to_json().encode("utf-8"))
        finally:
            os.close(fd)
    except BaseException:
        with contextlib.suppress(OSError):
            lock.unlink()
        raise
    return True


def acquire_lock(lock: Path, cache_file: Path, timeout: float, wait_longer: str) -> LockOwner:
    """
    Wait for and take the lock of a cache file.

    :param lock: The lock file
    :param cache_file: The cache file it protects (for messages)
    :param timeout: Seconds to wait for another owner
    :param wait_longer: How to wait longer, for the timeout message (e.g. "pass lock_timeout")
    :return: The record written into the lock (pass it to :func:`release_lock`)
    :raises TimeoutError: if another process still holds the lock after ``timeout`` seconds
    """
    me = LockOwner.me()
    deadline = time.monotonic() + timeout
    delay = _POLL_FIRST
    announced = False
    while not _try_create(lock, me):
        try:
            owner = _read_owner(lock)
        except FileNotFoundError:
            continue  # released since our attempt: try again at once
        if _stale_reason(lock, owner) is not None:
            reason = _remove_if_stale(lock)
            if reason is not None:
                warnings.warn(f"removed the stale lock {lock}: {reason}", RuntimeWarning, stacklevel=3)
                continue
        who = str(owner) if owner is not None else "an owner whose record is not readable (yet)"
        if not announced:
            warnings.warn(
                f"waiting for another process ({who}) that is building the same feature cache {cache_file} "
                f"(lock file {lock}, timeout {timeout:g} s)",
                RuntimeWarning,
                stacklevel=3,
            )
            announced = True
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise TimeoutError(
                f"gave up after {timeout:g} s waiting for the lock file {lock}, held by {who}, which is building "
                f"the feature cache {cache_file}. If no process is building it any more (e.g. one on another host "
                f"crashed), delete {lock} and retry; to wait longer {wait_longer}"
            )
        time.sleep(min(delay, remaining))
        delay = min(2 * delay, _POLL_MAX)
    return me


def release_lock(lock: Path, me: LockOwner) -> None:
    """Remove the lock if it still holds this process's record (someone may have deleted and re-taken it)."""
    try:
        owner = _read_owner(lock)
    except FileNotFoundError:
        owner = None
    if owner is not None and owner.token == me.token:
        try:
            _unlink(lock)
        except OSError as e:  # warn, not raise: this runs in a finally and must not hide the build's outcome
            warnings.warn(
                f"could not remove the lock file {lock} ({e}); other processes take it over once this one exits",
                RuntimeWarning,
                stacklevel=3,
            )
    else:
        warnings.warn(
            f"lock file {lock} was deleted or taken over by another process while this one built the cache; "
            "leaving it alone",
            RuntimeWarning,
            stacklevel=3,
        )
