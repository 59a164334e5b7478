"""Warm starts (solver.warm_start, host backends): the equilibria kept as starting points of later
solves, and the audits that compare a warm answer with the cold one."""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import NamedTuple

import numpy as np

# an audited warm solve whose displacements differ from the cold one's by more (max norm,
# relative to the cold one's largest) reached another equilibrium
SAME_EQUILIBRIUM = 1e-6
# warm starts stop once more than this fraction of audits differ
MIN_AUDITS, MAX_OTHER_EQUILIBRIA = 8, 0.1
# audits that found another equilibrium, recorded (difference, energies)
KEPT_OTHER_EQUILIBRIA = 100


class Start(NamedTuple):
    """Where a warm solve starts: a kept equilibrium's free displacements and prescribed ones, and
    the reference points of the design it was solved on (with contact its walls must not cross on
    the way to this design's)."""

    u_free: np.ndarray
    u_D: np.ndarray
    X: np.ndarray
    audit: bool  # also solve cold, and take the cold answer where they differ


class WarmStarts:
    """The equilibria kept as starting points of later solves: the last `size` converged ones, each
    with its actuation.  A solve starts from the one nearest in actuation, where that is nearer than
    rest.  Nothing here depends on threads: a batch takes its starts before it runs, and keeps its
    results and records its audits after, in sample order.

    A structure with several equilibria under one actuation (a near-mechanism, a buckled wall) can
    reach another from a warm start than from rest.  Every `audit_every`-th warm solve is therefore
    also solved cold; where the two differ the cold answer is taken, and once more than `max_other`
    of at least MIN_AUDITS audits differed, warm starts stop for the rest of the run (`stopped` says
    why).  `clear()` (the trainer's, at every checkpoint) drops what is kept, so that a run resumed
    there solves exactly as one not interrupted; the audits' tallies (`verdict`) go on over the run
    and into the checkpoint (`restore`): counted anew at every checkpoint, a run that checkpoints
    often would never reach MIN_AUDITS.  `stats` and `other_equilibria` count everything since the
    simulator was built (they decide nothing)."""

    def __init__(self, size: int, audit_every: int, max_other: float = MAX_OTHER_EQUILIBRIA):
        self.size, self.audit_every, self.max_other = size, audit_every, max_other
        self.other_equilibria: list[dict] = []
        self.stats = {
            "warm_solves": 0,
            "warm_converged": 0,
            "warm_iterations": 0,
            "cold_solves": 0,
            "cold_iterations": 0,
            "audits": 0,
            "audits_same": 0,
            "audits_within_1e-8": 0,
            "audit_largest_difference": 0.0,
            "stops": 0,
        }
        self._lock = threading.Lock()
        self._audits = self._other = 0
        self.enabled, self.stopped = True, ""
        self.clear()

    def clear(self) -> None:
        """Nothing kept (the audits' tallies, and so whether warm starts are on, stay)."""
        # (d, u_D, u_free, X)
        self._kept: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._taken = 0

    @property
    def verdict(self) -> tuple[int, int]:
        """(audits, of them on another equilibrium) over the run: what decides whether warm starts
        stop."""
        return self._audits, self._other

    def restore(self, audits: int, other: int) -> None:
        """A checkpoint's tallies: a resumed run goes on as the run it continues (stopped where it
        was)."""
        self._audits, self._other = int(audits), int(other)
        self.enabled, self.stopped = True, ""
        self._judge(count=False)

    def _judge(self, count: bool = True) -> None:
        if (
            self.enabled
            and self._audits >= MIN_AUDITS
            and self._other > self.max_other * self._audits
        ):
            self.enabled, self._kept = False, []
            self.stats["stops"] += int(count)
            self.stopped = (
                f"{self._other} of {self._audits} audited warm solves reached another equilibrium "
                f"than the cold solve: this design has several under one actuation"
            )

    def start(self, d: np.ndarray) -> Start | None:
        """The start of a solve at actuation d: the kept equilibrium nearest to it, None where
        nothing kept is nearer than rest (or warm starts are off)."""
        if not (self.enabled and self._kept):
            return None
        dist = [np.linalg.norm(d - kept[0]) for kept in self._kept]
        i = int(np.argmin(dist))
        if not dist[i] < np.linalg.norm(d):
            return None
        self._taken += 1
        _, u_D, u_free, X = self._kept[i]
        return Start(u_free, u_D, X, self.audit_every > 0 and self._taken % self.audit_every == 0)

    def keep(self, d, u_D, u_free, X) -> None:
        if self.enabled:
            self._kept.append((np.array(d), np.array(u_D), np.array(u_free), np.array(X)))
            del self._kept[: -self.size]

    def record(self, **counts) -> None:
        with self._lock:  # a batch's samples report from several threads
            for k, v in counts.items():
                self.stats[k] += v

    def audited(self, audit: "Audit") -> None:
        """Record an audit, and stop warm starts where too many found another equilibrium."""
        st, same = self.stats, audit.same
        st["audits"] += 1
        st["audits_same"] += int(same)
        st["audits_within_1e-8"] += int(audit.difference <= 1e-8)
        st["audit_largest_difference"] = max(st["audit_largest_difference"], audit.difference)
        if not same and len(self.other_equilibria) < KEPT_OTHER_EQUILIBRIA:
            self.other_equilibria.append(audit._asdict())
        self._audits += 1
        self._other += int(not same)
        self._judge()

    @contextmanager
    def paused(self):
        """Cold solves only (a run's final evaluation, whose metric is the cold solves', and
        sim.solve)."""
        enabled, self.enabled = self.enabled, False
        try:
            yield
        finally:
            self.enabled = enabled and not self.stopped


class Audit(NamedTuple):
    """A warm solve also solved cold: the displacements' relative difference (max norm, relative to
    the cold one's largest), and where they differ, the two equilibria's energies."""

    difference: float
    energy_warm: float | None = None
    energy_cold: float | None = None

    @property
    def same(self) -> bool:
        return self.difference <= SAME_EQUILIBRIUM
