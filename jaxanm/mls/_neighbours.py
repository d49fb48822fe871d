"""Neighbour candidates of a moving cloud (a Verlet list), for rebuilding its stencils."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ..checkpoint import stored_type

M_MAX_MULTIPLE = 8
"""The default stencil width is the largest neighbour count rounded up to a multiple of this."""


@stored_type("mls.NeighbourList")
class NeighbourList:
    """Neighbour candidates of a moving cloud (a Verlet list), for rebuilding its stencils.

    One cKDTree query collects, for every evaluation point (the nodes themselves, or moving
    targets such as material points), the nodes within its own ``h + skin`` (on a graded cloud
    h varies tenfold: a common radius would give the fine zone's points a hundred times the
    candidates they need).  Until the nodes and the targets have together moved more than
    the ``skin`` left above each point's present h (the largest node move plus that target's
    move; for the nodes themselves twice the largest move), every pair now within ``h`` is
    among those candidates, so the nearest ``m`` within ``h`` are found by sorting the
    candidates' exact distances; beyond that, or for other sizes, the list is remade.  The result is what
    ``cKDTree.query(targets, k=m, distance_upper_bound=h)`` returns (distances computed the
    same way, ``inf`` where fewer than ``m`` are within ``h``; rows with a candidate at ``h``
    to round-off are left to cKDTree), up to the order of equidistant points.  Plain numpy
    state: checkpoints store it as it is (:meth:`to_plain`).

    Parameters
    ----------
    skin : float
        Extra search radius (same units as the points).
    """

    def __init__(self, skin: float):
        self.skin = float(skin)
        self.reference: np.ndarray | None = None   # (N, 2) node positions when the list was made
        self.targets: np.ndarray | None = None     # (T, 2) target positions then (None: the nodes themselves)
        self.reach: np.ndarray | None = None       # (T,) the radius each target's candidates cover
        self.candidates: np.ndarray | None = None  # (T, K) node indices, N where absent
        self.rebuilds = 0
        self.width = 0          # the widest stencil it has given (m=None): widths only grow

    STATE = ("skin", "reference", "targets", "reach", "candidates", "rebuilds", "width")
    """The attributes that make up the list (all of them: what :meth:`to_plain` stores)."""

    def to_plain(self) -> dict:
        """The list's state, ``{name: value}`` for each name of :data:`STATE`."""
        return {name: getattr(self, name) for name in self.STATE}

    @classmethod
    def from_plain(cls, state: dict) -> NeighbourList:
        """The list :meth:`to_plain` stored (:class:`KeyError` for a missing attribute)."""
        new = cls(state["skin"])
        for name in cls.STATE:
            setattr(new, name, state[name])
        return new

    @staticmethod
    def _moved(now, then) -> float:
        return float(np.sqrt(np.max(np.sum((now - then) ** 2, axis=1))))

    def _stale(self, points, targets, h) -> bool:
        reference, reach, then = self.reference, self.reach, self.targets
        if (reference is None or reach is None or reference.shape != points.shape or reach.shape != h.shape
                or (targets is None) != (then is None)):
            return True
        moved = self._moved(points, reference)
        if targets is None or then is None:
            moved = 2.0 * moved
        elif targets.shape != then.shape:
            return True
        else:
            moved = moved + np.sqrt(np.sum((targets - then) ** 2, axis=1))
        return not np.all(h + moved <= reach)

    def query(self, points: np.ndarray, h: np.ndarray, m: int | None, targets: np.ndarray | None = None):
        """``(dist, idx, m)``: the ``m`` nearest nodes closer than ``nextafter(h.max())`` to each
        target (default: to each node, itself first).  ``h`` (T,): radius per target; ``m=None``:
        the largest count within ``h``, rounded up to a multiple of :data:`M_MAX_MULTIPLE`, and
        at least the widest this list has given before (targets that move in and out of a
        denser zone would otherwise change the width, and the compiled kernel, back and forth;
        the extra columns are padding, outside every support)."""
        hmax = float(np.nextafter(h.max(), np.inf))
        centers = points if targets is None else targets
        h_at = np.nextafter(np.broadcast_to(np.asarray(h, dtype=np.float64), (len(centers),)), np.inf)
        if self._stale(points, targets, h_at):
            tree = cKDTree(points)
            reach = h_at + self.skin
            k = int(tree.query_ball_point(centers, r=reach, return_length=True).max())
            dist, cand = tree.query(centers, k=max(k, 1), distance_upper_bound=float(reach.max()))
            dist, cand = dist.reshape(len(centers), -1), cand.reshape(len(centers), -1)
            cand[~(dist <= reach[:, None])] = points.shape[0]  # beyond this target's own reach
            self.candidates, self.reference, self.reach = cand, points.copy(), reach
            self.targets = None if targets is None else targets.copy()
            self.rebuilds += 1
        n, cand = points.shape[0], self.candidates
        assert cand is not None  # made by the first query, which is always stale
        # coordinates gathered one axis at a time (a 1-D take is faster than one of rows of 2)
        dx = np.append(points[:, 0], np.inf)[cand] - centers[:, :1]  # index n: absent candidate
        dy = np.append(points[:, 1], np.inf)[cand] - centers[:, 1:]
        d = np.sqrt(dx * dx + dy * dy)
        # A node at the radius to round-off (the polar cloud has them: the tool's third ring
        # is 3 dr = h from its centre) is in or out by round-off, and cKDTree's pruning of
        # its boxes (rounded box distances, off by ulps of h) decides it its own way:
        # let cKDTree decide those rows, so that the stencils are the ones it gives (the
        # weight there, exp(-1/c^2), is not negligible).
        band = 1e-12 * (hmax + np.abs(points).max() + np.abs(centers).max())
        rows = np.flatnonzero(((np.abs(d - hmax) <= band) | (np.abs(d - h[:, None]) <= band)).any(axis=1))
        tree = cKDTree(points) if rows.size else None
        if m is None:
            counts = (d <= h[:, None]).sum(axis=1)
            if tree is not None:
                counts[rows] = tree.query_ball_point(centers[rows], r=h[rows], return_length=True)
            m = max(M_MAX_MULTIPLE * max(1, math.ceil(int(counts.max()) / M_MAX_MULTIPLE)), self.width)
            self.width = m  # never narrower than before: a new width recompiles the MLS kernel
        flat = (np.argsort(d, axis=1, kind="stable")[:, :m]
                + cand.shape[1] * np.arange(len(centers))[:, None])
        dist, idx = d.reshape(-1)[flat], cand.reshape(-1)[flat]
        out = ~(dist < hmax)  # strict, as cKDTree's distance_upper_bound
        dist[out], idx[out] = np.inf, n
        if dist.shape[1] < m:  # fewer candidates than the stencil width
            pad = m - dist.shape[1]
            dist = np.concatenate([dist, np.full((len(centers), pad), np.inf)], axis=1)
            idx = np.concatenate([idx, np.full((len(centers), pad), n)], axis=1)
        if tree is not None:
            dist[rows], idx[rows] = (a.reshape(rows.size, m) for a in
                                     tree.query(centers[rows], k=m, distance_upper_bound=hmax))
        return dist, idx, m

