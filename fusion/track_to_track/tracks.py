"""What a track list holds: network-wide track ids, the issuer of new ones, and one track's checked estimate
(see the package's docstring for identity across the network)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..linalg import is_spd

Array = np.ndarray

#: the statuses a track may have in a list (deleted tracks are not published)
TRACK_STATUSES = ("tentative", "confirmed")
#: the fusion rule of :func:`fuse_tracks` by default: CI with the fast-CI weights (Niehsen 2002), a fifth of
#: ``ci-trace``'s cost per track (0.2 ms against 0.9 ms for two 4-D estimates)
DEFAULT_TRACK_RULE = "ci-fast"


@dataclass(frozen=True, order=True)
class TrackId:
    """A network-wide track identity; ordered oldest first (``born``), then by ``node`` and ``serial``."""

    born: int
    node: int
    serial: int


class TrackIdIssuer:
    """New ids for the tracks node ``node`` starts: ``TrackId(step, node, serial)`` with a serial counting up
    from ``first_serial``. Unique across restarts: a restarted node starts again at serial 0, but at a later
    step than any id its earlier run issued (a restart within the same step must pass a ``first_serial`` past
    the earlier run's, e.g. its incarnation times a bound on the tracks one run starts)."""

    def __init__(self, node: int, first_serial: int = 0) -> None:
        if node < 0 or first_serial < 0:
            raise ValueError(f"node and first_serial must be >= 0, got {node} and {first_serial}")
        self.node, self._serial = int(node), int(first_serial)

    def issue(self, step: int) -> TrackId:
        """The next id, for a track started at ``step``."""
        self._serial += 1
        return TrackId(int(step), self.node, self._serial - 1)


@dataclass(frozen=True, eq=False)
class TrackEstimate:
    """One track of a list: its id, Gaussian estimate ``mean (n,)``, ``cov (n, n)``, status, step,
    ``misses``, the steps since its holder last measured the target (0: measured at this step), and ``existence``.
    Checked on construction (ValueError naming the field)."""

    id: TrackId
    mean: Array
    cov: Array
    status: str = "confirmed"
    step: int = 0
    misses: int = 0
    #: the probability that the target exists (a PMBM node's Bernoulli; 1 for an M-of-N track)
    existence: float = 1.0

    def __post_init__(self) -> None:
        mean, cov = np.asarray(self.mean, dtype=float), np.asarray(self.cov, dtype=float)
        if mean.ndim != 1 or mean.size == 0 or cov.shape != (mean.size, mean.size):
            raise ValueError(f"track {self.id}: mean {mean.shape} and cov {cov.shape} are not (n,) and (n, n)")
        if not np.isfinite(mean).all():
            raise ValueError(f"track {self.id}: mean has non-finite values")
        if not is_spd(cov):
            raise ValueError(f"track {self.id}: cov is not symmetric positive definite")
        if self.status not in TRACK_STATUSES:
            raise ValueError(f"track {self.id}: status {self.status!r} not one of {TRACK_STATUSES}")
        if not (isinstance(self.misses, int) and self.misses >= 0):
            raise ValueError(f"track {self.id}: misses {self.misses!r} is not a count")
        if not (isinstance(self.existence, (int, float)) and 0.0 < self.existence <= 1.0):
            raise ValueError(f"track {self.id}: existence {self.existence!r} is not a probability in (0, 1]")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", 0.5 * (cov + cov.T))

    @classmethod
    def checked_before(cls, id: TrackId, mean: Array, cov: Array, status: str = "confirmed", step: int = 0,
                       misses: int = 0, existence: float = 1.0) -> TrackEstimate:
        """An estimate whose values were checked where they came from (a decoded track list, which refuses any
        that is not finite or SPD; a fusion rule's output): built without the checks of the constructor, whose
        positive-definiteness test is most of a receiver's time on a list of many tracks."""
        obj = object.__new__(cls)
        for name, value in (("id", id), ("mean", mean), ("cov", cov), ("status", status), ("step", step),
                            ("misses", misses), ("existence", existence)):
            object.__setattr__(obj, name, value)
        return obj
