"""Firmware instance numbers claimed across processes and held for a run's life.

Runs side by side each need an instance of their own (ArduPilot's ``-I N`` moves its TCP ports
by ``10 N``, PX4's ``-i N`` its UDP ports). An instance whose ports nobody has bound looks free,
but looking is not taking: a run binds its ports only once its firmware has started, so two runs
that looked at the same moment took the same one (both got ArduPilot's 82 while another process
held 80 and 81). :func:`claimed` first takes an exclusive lock on the instance's lock file
(``fcntl.flock``, not waiting), then looks at the ports, and holds the lock until its block ends.
The kernel drops the lock when the holder's file is closed, also when it exits or crashes: a
lock file left behind claims nothing. Lock files live in ``$FCMPC_INSTANCE_LOCK_DIR``, else the
system's temporary folder (every process of a machine must see the same folder).
"""
from __future__ import annotations

import fcntl
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["LOCK_DIR_ENV", "claimed", "claimed_instance", "lock_path"]

LOCK_DIR_ENV = "FCMPC_INSTANCE_LOCK_DIR"


def lock_path(kind: str, instance: int) -> Path:
    """The lock file of instance ``instance`` of firmware ``kind`` ("ardupilot", "px4")."""
    folder = Path(os.environ.get(LOCK_DIR_ENV) or tempfile.gettempdir())
    return folder / f"fcmpc-{kind}-instance-{instance}.lock"


def _lock(path: Path) -> int | None:
    """An open descriptor of ``path`` holding its exclusive lock, or None if another holds it."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except PermissionError:     # another user's lock file: theirs
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:             # BlockingIOError: claimed (by another process, or another claim of ours)
        os.close(fd)
        return None
    return fd


@contextmanager
def claimed(kind: str, candidates: Iterable[int], free: Callable[[int], bool]) -> Iterator[int]:
    """The first of ``candidates`` that no one claims (in any process) and ``free`` finds free (its
    ports unbound), claimed until the block ends; RuntimeError when there is none. A second claim
    in the same process is refused as another process's is (the lock is the open file's)."""
    candidates = list(candidates)
    for instance in candidates:
        fd = _lock(lock_path(kind, instance))
        if fd is None:
            continue
        if not free(instance):
            os.close(fd)
            continue
        try:
            yield instance
        finally:
            os.close(fd)        # the lock goes with the descriptor
        return
    raise RuntimeError(f"no free {kind} instance among {sorted(candidates)}: each is claimed by another run "
                       "or its ports are bound")


@contextmanager
def claimed_instance(kind: str, low: int, high: int, start: int | None = None) -> Iterator[int]:
    """An instance of firmware ``kind`` ("ardupilot": ports unbound; "px4": also no ``/tmp/px4_lock-N``)
    in ``low``..``high``, the first from ``start`` on (``low`` when None), round the range, that no one
    claims and whose ports nobody has bound: :func:`claimed` until the block ends."""
    if kind == "ardupilot":
        from fcmpc.firmware.ardupilot import instance_free as free
    elif kind == "px4":
        from fcmpc.firmware.px4 import px4_instance_free as free
    else:
        raise ValueError(f"firmware kind {kind!r}: 'ardupilot' or 'px4'")
    start = low + ((low if start is None else start) - low) % (high - low + 1)
    with claimed(kind, [*range(start, high + 1), *range(low, start)], free) as instance:
        yield instance
