"""A stand-in for the size/rank calls of an mpi4py communicator, for in-process tests of what needs nothing else
(``slab_rows``, ``SlabFFT``'s blocks and Parseval weights); a collective would be a test error."""

from __future__ import annotations


class SizeRankComm:
    """Rank ``rank`` of ``size``: ``Get_size``, ``Get_rank``; ``Allgather`` refuses (not used)."""

    def __init__(self, size: int, rank: int) -> None:
        self.size, self.rank = size, rank

    def Get_size(self) -> int:
        return self.size

    def Get_rank(self) -> int:
        return self.rank

    def Allgather(self, a, b) -> None:
        raise AssertionError("not used")
