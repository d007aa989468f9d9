"""An in-process stand-in for an mpi4py communicator: ``size`` threads, one per rank, exchanging through shared
memory (the few methods gapsweep.core.slab, gfmd.distributed and gfmd._coarse call: Get_size, Get_rank,
Allgather, Alltoallv, bcast, Sendrecv). It lets the validation suite run a distributed transform or solve on any
rank count, odd ones included, without mpiexec. Each collective is two barriers (post, then read), so a rank that
fails breaks the barrier and the others stop instead of hanging."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np

TIMEOUT_S = 60.0  # a barrier waits this long at most: a missing rank is a failure, not a hang


class _World:
    def __init__(self, size: int) -> None:
        self.size = size
        self.barrier = threading.Barrier(size, timeout=TIMEOUT_S)
        self.slots: list[Any] = [None] * size


class ThreadComm:
    """Rank ``rank`` of a world of threads (mpi4py's method names and buffer conventions)."""

    def __init__(self, world: _World, rank: int) -> None:
        self._w, self._rank = world, rank

    def Get_size(self) -> int:
        return self._w.size

    def Get_rank(self) -> int:
        return self._rank

    def py2f(self) -> int:
        return -1

    def _exchange(self, item: Any) -> list[Any]:
        """Post ``item``; return every rank's item (a copy of the list); all ranks leave together."""
        w = self._w
        w.slots[self._rank] = item
        w.barrier.wait()
        items = list(w.slots)
        w.barrier.wait()
        return items

    def Allgather(self, send: Any, recv: Any) -> None:
        items = self._exchange(np.array(send, copy=True))
        recv[...] = np.stack([np.reshape(a, recv.shape[1:]) for a in items])

    def Alltoallv(self, send: list, recv: list) -> None:
        sbuf, (scounts, sdispl) = send
        rbuf, (rcounts, rdispl) = recv
        items = self._exchange((np.array(sbuf, copy=True), np.asarray(scounts), np.asarray(sdispl)))
        me = self._rank
        for src, (buf, sc, sd) in enumerate(items):
            n = int(sc[me])
            assert n == int(rcounts[src]), "Alltoallv counts disagree"
            rbuf[int(rdispl[src]):int(rdispl[src]) + n] = buf[int(sd[me]):int(sd[me]) + n]

    def bcast(self, value: Any, root: int = 0) -> Any:
        return self._exchange(value)[root]

    def Sendrecv(self, sendbuf: Any, dest: int, recvbuf: Any, source: int) -> None:
        items = self._exchange((dest, np.array(sendbuf, copy=True)))
        to, buf = items[source]
        assert to == self._rank, "Sendrecv partners disagree"
        recvbuf[...] = buf


def run_ranks(size: int, fn: Callable[[ThreadComm], Any]) -> list[Any]:
    """``fn(comm)`` on ``size`` threads, one per rank; their results in rank order (the first error re-raised)."""
    world = _World(size)
    out: list[Any] = [None] * size
    errors: list[BaseException] = []

    def target(rank: int) -> None:
        try:
            out[rank] = fn(ThreadComm(world, rank))
        except BaseException as e:  # re-raised below in the caller's thread
            errors.append(e)
            world.barrier.abort()

    threads = [threading.Thread(target=target, args=(r,), daemon=True) for r in range(size)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        real = [e for e in errors if not isinstance(e, threading.BrokenBarrierError)]
        raise (real or errors)[0]
    return out
