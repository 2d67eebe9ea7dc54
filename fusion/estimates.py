"""Typed single-node estimates: what one tracker holds between steps and what it shares.

Batched code (local filters, the network simulator) works on :class:`~zentrack.fusion.linalg.GaussianState`
stacks; one tracker process holds one estimate of one of these types (unbatched arrays):

- :class:`GaussianEstimate` ``mean (n,)``, ``cov (n, n)``: Kalman-type filters (paper 0, 003);
- :class:`InformationEstimate` ``matrix (n, n)``, ``vector (n,)``: information filters (paper 2, 004);
- :class:`ParticleEstimate` ``samples (P, n)``, ``weights (P,)``: particle filters (paper 1), summarised by
  the weighted mean and covariance for fusion;
- :class:`CompositeEstimate`: named blocks fused separately (paper 4: ``"kinematic"`` and ``"extent"``).

Every estimate exports its information blocks (``(Y, y) = (P^-1, P^-1 x)``, paper 0 Algorithm 2 line 9),
which is all a fusion rule sees, and its kinematic part, which is what is scored against the truth.
The first ``kinematic_dim`` components of a state are the kinematic ones.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from .linalg import GaussianState, InformationPair, from_information, symmetrize, to_information

Array = np.ndarray

#: the block name of a plain (single-block) estimate
STATE_BLOCK = "state"
#: the block of a composite estimate compared with the truth
KINEMATIC_BLOCK = "kinematic"


class Estimate(ABC):
    """One node's estimate: information blocks for fusion, a Gaussian kinematic part for scoring."""

    kinematic_dim: int

    @abstractmethod
    def information_blocks(self) -> dict[str, InformationPair]:
        """Block name -> unbatched information pair ``(n, n)``, ``(n,)``."""

    @abstractmethod
    def kinematic(self) -> GaussianEstimate:
        """The kinematic part as a Gaussian (mean ``(kinematic_dim,)``)."""


def _check_kinematic_dim(kinematic_dim: int, n: int) -> None:
    if not 1 <= kinematic_dim <= n:
        raise ValueError(f"kinematic_dim: expected 1..{n}, got {kinematic_dim}")


@dataclass
class GaussianEstimate(Estimate):
    """Mean ``(n,)`` and covariance ``(n, n)``; ``kinematic_dim`` defaults to n."""

    mean: Array
    cov: Array
    kinematic_dim: int = -1

    def __post_init__(self) -> None:
        self.mean = np.asarray(self.mean, dtype=float)
        self.cov = np.asarray(self.cov, dtype=float)
        if self.mean.ndim != 1:
            raise ValueError(f"mean: expected shape (n,), got {self.mean.shape}")
        n = self.mean.shape[0]
        if self.cov.shape != (n, n):
            raise ValueError(f"cov: expected shape {(n, n)}, got {self.cov.shape}")
        if self.kinematic_dim == -1:
            self.kinematic_dim = n
        _check_kinematic_dim(self.kinematic_dim, n)

    @property
    def dim(self) -> int:
        return int(self.mean.shape[0])

    @classmethod
    def from_state(cls, state: GaussianState, kinematic_dim: int = -1, index: int = 0) -> GaussianEstimate:
        """Row ``index`` of a batched state (a batch of one by default)."""
        return cls(state.mean[index], state.cov[index], kinematic_dim)

    def to_state(self) -> GaussianState:
        """A batch of one, ``(1, n)`` and ``(1, n, n)`` (views of this estimate's arrays)."""
        return GaussianState(self.mean[None], self.cov[None])

    def gaussian(self) -> GaussianEstimate:
        return self

    def information(self) -> InformationEstimate:
        pair = to_information(self.to_state())
        return InformationEstimate(pair.matrix[0], pair.vector[0], self.kinematic_dim)

    def information_blocks(self) -> dict[str, InformationPair]:
        return {STATE_BLOCK: to_information(GaussianState(self.mean, self.cov))}  # unbatched: (n, n), (n,)

    def kinematic(self) -> GaussianEstimate:
        n = self.kinematic_dim
        return GaussianEstimate(self.mean[:n], self.cov[:n, :n], n)


@dataclass
class InformationEstimate(Estimate):
    """Information matrix ``Y = P^-1`` ``(n, n)`` and vector ``y = P^-1 x`` ``(n,)``."""

    matrix: Array
    vector: Array
    kinematic_dim: int = -1

    def __post_init__(self) -> None:
        self.matrix = np.asarray(self.matrix, dtype=float)
        self.vector = np.asarray(self.vector, dtype=float)
        if self.vector.ndim != 1:
            raise ValueError(f"vector: expected shape (n,), got {self.vector.shape}")
        n = self.vector.shape[0]
        if self.matrix.shape != (n, n):
            raise ValueError(f"matrix: expected shape {(n, n)}, got {self.matrix.shape}")
        if self.kinematic_dim == -1:
            self.kinematic_dim = n
        _check_kinematic_dim(self.kinematic_dim, n)

    @classmethod
    def from_pair(cls, pair: InformationPair, kinematic_dim: int = -1, index: int = 0) -> InformationEstimate:
        """Row ``index`` of a batched pair (a batch of one by default)."""
        return cls(pair.matrix[index], pair.vector[index], kinematic_dim)

    def to_pair(self) -> InformationPair:
        """A batch of one, ``(1, n, n)`` and ``(1, n)``."""
        return InformationPair(self.matrix[None], self.vector[None])

    def gaussian(self) -> GaussianEstimate:
        """``(Y, y) -> (Y^-1, Y^-1 y)`` (paper 0 Algorithm 2 line 10)."""
        return GaussianEstimate.from_state(from_information(self.to_pair()), self.kinematic_dim)

    def information_blocks(self) -> dict[str, InformationPair]:
        return {STATE_BLOCK: InformationPair(self.matrix, self.vector)}

    def kinematic(self) -> GaussianEstimate:
        return self.gaussian().kinematic()


@dataclass
class ParticleEstimate(Estimate):
    """Weighted samples ``(P, n)``, weights ``(P,)`` (non-negative, normalised on use)."""

    samples: Array
    weights: Array
    kinematic_dim: int = -1

    def __post_init__(self) -> None:
        self.samples = np.asarray(self.samples, dtype=float)
        self.weights = np.asarray(self.weights, dtype=float)
        if self.samples.ndim != 2 or self.samples.shape[0] < 1:
            raise ValueError(f"samples: expected shape (P, n) with P >= 1, got {self.samples.shape}")
        if self.weights.shape != self.samples.shape[:1]:
            raise ValueError(f"weights: expected shape {self.samples.shape[:1]}, got {self.weights.shape}")
        if not np.all(np.isfinite(self.weights)) or np.any(self.weights < 0) or not self.weights.sum() > 0:
            raise ValueError("weights: must be finite, non-negative and not all zero")
        if self.kinematic_dim == -1:
            self.kinematic_dim = self.samples.shape[1]
        _check_kinematic_dim(self.kinematic_dim, self.samples.shape[1])

    def gaussian(self) -> GaussianEstimate:
        """Weighted mean ``sum_p w_p x_p`` and covariance ``sum_p w_p (x_p - mean)(x_p - mean)^T``."""
        w = self.weights / self.weights.sum()
        mean = w @ self.samples
        d = self.samples - mean
        cov = symmetrize((d * w[:, None]).T @ d)
        return GaussianEstimate(mean, cov, self.kinematic_dim)

    summary = gaussian

    def information_blocks(self) -> dict[str, InformationPair]:
        return self.gaussian().information_blocks()

    def kinematic(self) -> GaussianEstimate:
        return self.gaussian().kinematic()


@dataclass
class CompositeEstimate(Estimate):
    """Named blocks fused separately; the ``"kinematic"`` block is scored against the truth.

    Its information blocks are one per block (a nested composite's as ``outer.inner``).
    """

    blocks: dict[str, Estimate] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if KINEMATIC_BLOCK not in self.blocks:
            raise ValueError(f"blocks: a composite estimate needs a {KINEMATIC_BLOCK!r} block, got {list(self.blocks)}")
        for name, block in self.blocks.items():
            if not isinstance(block, Estimate):
                raise ValueError(f"blocks[{name!r}]: expected an Estimate, got {type(block).__name__}")

    @property
    def kinematic_dim(self) -> int:  # type: ignore[override]
        return self.blocks[KINEMATIC_BLOCK].kinematic_dim

    def information_blocks(self) -> dict[str, InformationPair]:
        out: dict[str, InformationPair] = {}
        for name, block in self.blocks.items():
            inner = block.information_blocks()
            if list(inner) == [STATE_BLOCK]:
                out[name] = inner[STATE_BLOCK]
            else:
                out.update({f"{name}.{sub}": pair for sub, pair in inner.items()})
        return out

    def kinematic(self) -> GaussianEstimate:
        return self.blocks[KINEMATIC_BLOCK].kinematic()
