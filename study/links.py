"""Links cut per step in the batched simulator: which messages each node receives in each fusion, who fused alone,
and the update of those nodes' rows (:mod:`zentrack.fusion.isolation`), for
:func:`~zentrack.study.simulator.run_distributed` with ``links``.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from zentrack.fusion.filters import LocalFilter
from zentrack.fusion.isolation import fused_alone
from zentrack.fusion.linalg import GaussianState

Array = np.ndarray

#: the update of an isolated node's rows: ``alone(filter, prior, z, sensors, noise) -> posterior``
IsolatedUpdate = Callable[[LocalFilter, GaussianState, Array, Array, Array], GaussianState]


def cut_links(steps: int, nodes: int, node: int, start: int, length: int) -> Array:
    """``(K, M, M)`` links with ``node`` cut both ways in the fusions that make the priors of steps ``start`` to
    ``start + length - 1`` (fusions ``start - 1`` to ``start + length - 2``)."""
    links = np.ones((steps, nodes, nodes), dtype=bool)
    window = slice(start - 1, start + length - 1)
    links[window, node, :] = False
    links[window, :, node] = False
    return links


def link_mask(links: Array, runs: int, steps: int, nodes: int) -> Array:
    """``links`` (``(K, M, M)``, the same in every run, or ``(R, K, M, M)``) as booleans with every node's own
    message present; ValueError on another shape."""
    a = np.asarray(links, dtype=bool)
    if a.shape not in ((steps, nodes, nodes), (runs, steps, nodes, nodes)):
        raise ValueError(f"links: expected shape ({steps}, {nodes}, {nodes}) or ({runs}, {steps}, {nodes}, {nodes}), "
                         f"got {a.shape}")
    return a | np.eye(nodes, dtype=bool)


def isolated_rows(present: Array, adjacency: Array, runs: int) -> Array:
    """``(R, K, M)``: the nodes that fused alone in the fusion of step k (:func:`~zentrack.fusion.isolation.fused_alone`)."""
    alone = fused_alone(present, (np.asarray(adjacency) != 0) & ~np.eye(adjacency.shape[-1], dtype=bool))
    return np.broadcast_to(alone, (runs,) + alone.shape[-2:])


def update_isolated_rows(filt: LocalFilter, prior: GaussianState, post: GaussianState, z: Array, sensors: Array,
                         noise: Array, rows_mask: Array, alone: IsolatedUpdate) -> GaussianState:
    """``post`` with the rows of ``rows_mask`` (isolated, with a measurement) updated from ``prior`` by ``alone``
    instead; ``post`` itself where there are none or ``filt`` has no nominal transition."""
    rows = np.flatnonzero(rows_mask)
    if len(rows) == 0 or filt.nominal_transition() is None:
        return post
    noise_rows = noise[rows] if noise.ndim == 3 else noise
    held = alone(filt, GaussianState(prior.mean[rows], prior.cov[rows]), z[rows], sensors[rows], noise_rows)
    mean, cov = post.mean.copy(), post.cov.copy()
    mean[rows], cov[rows] = held.mean, held.cov
    return GaussianState(mean, cov)
