"""Data parallelism over MPI: rank 0 owns the run directory; gradients are summed with Allreduce."""

from __future__ import annotations

import numpy as np

from ..errors import ConfigError


class World:
    """The MPI world, or a single process when not launched under mpiexec."""

    def __init__(self):
        try:
            from mpi4py import MPI

            self.comm = MPI.COMM_WORLD
            self._sum = MPI.SUM
        # pragma: no cover - mpi4py is a dependency; keep single-process use working
        except ImportError:
            self.comm = None
        self.rank = self.comm.Get_rank() if self.comm else 0
        self.size = self.comm.Get_size() if self.comm else 1
        # ranks sharing this machine (they share its cores)
        self.local_size = (
            self.comm.Split_type(MPI.COMM_TYPE_SHARED).Get_size() if self.size > 1 else 1
        )

    @property
    def is_root(self) -> bool:
        return self.rank == 0

    def allreduce_sum(self, x: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=np.float64)
        if self.size == 1:
            return x
        out = np.empty_like(x)
        self.comm.Allreduce(x, out, op=self._sum)
        return out

    def allreduce_record(self, record: dict) -> dict:
        """Every rank's record (name -> number or array) summed over the ranks, in one Allreduce."""
        parts = {k: np.asarray(v, dtype=np.float64) for k, v in record.items()}
        total = self.allreduce_sum(np.concatenate([v.ravel() for v in parts.values()]))
        ends = np.cumsum([v.size for v in parts.values()])
        return {
            k: piece.reshape(v.shape)
            for (k, v), piece in zip(parts.items(), np.split(total, ends[:-1]))
        }

    def bcast(self, obj):
        return obj if self.size == 1 else self.comm.bcast(obj, root=0)

    def shard(self, n: int) -> slice:
        """This rank's contiguous slice of a global batch of n samples."""
        if n % self.size:
            raise ConfigError(
                f"trainer.batch_size ({n}) must be a multiple of the number of MPI ranks "
                f"({self.size})"
            )
        k = n // self.size
        return slice(self.rank * k, (self.rank + 1) * k)
