"""Step 1 of :meth:`~darces_matcher.matcher.Matcher.match`: the LN's nodes as the search
takes them, and their tolerances d_D, gates and weights from the LN error model.

Each LN node with a finite position gets a 1-sigma position error per axis
(:meth:`LnTolerances.node_sigma`: from the records' covariance, relative to an anchor
node, floored); with the GN's error it sets the node tolerance d_D, the verification gate,
the edge tolerance of a triangle and the node's weight in a fit
(:meth:`LnTolerances._tolerances`). Where a fit of the LN is judged precise
(``max_position_sigma_m``) is set here too: every node, or the newest one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.gn_index import GnIndex
from darces_matcher.ln_drift import turn_variance
from darces_matcher.vote import predicted_variance
from roi_network.network import RoiNetwork
from roi_network.records import as_records, xy


@dataclass(frozen=True)
class Tolerances:
    """Step 1's outcome for the finite nodes of an LN, in their order.

    Attributes:
        node_tol: (K,) node tolerance d_D, metres.
        gate: (K,) verification gate, metres.
        edge_tol: (K, K) tolerance of the length of each edge, metres.
        weights: (K,) weight of each node in a fit, 1 / m^2.
        groups: the nodes' per-class query plan (:meth:`GnIndex.label_groups`).
        precise: the most precise nodes and their query plan (the cheap confirmation of
            hypotheses before the full vote).
    """

    node_tol: np.ndarray
    gate: np.ndarray
    edge_tol: np.ndarray
    weights: np.ndarray
    groups: list
    precise: tuple[np.ndarray, list]


class LnTolerances:
    """The LN error model of :class:`~darces_matcher.matcher.Matcher` (a mixin: it uses
    the matcher's settings and GN index, and keeps where its last LN is judged)."""

    config: MatchConfig
    index: GnIndex
    _judged: np.ndarray | None

    def node_sigma(self, records: np.ndarray, ln_sigma: np.ndarray | None,
                   anchor_newest: bool = False,
                   odom_cov: np.ndarray | None = None) -> np.ndarray:
        """1-sigma position error per axis of each LN node, metres.

        From ``ln_sigma`` when given, else from the records' covariance (cov_xx, cov_yy),
        relative to the least uncertain node when ``ln_sigma_relative`` (to the most
        uncertain one, the newest, with ``anchor_newest``); with ``odom_cov``, the (K, 3,
        3) odometry (x, y, yaw) covariance each node was observed with, less what the
        anchor's heading error explains (:func:`~darces_matcher.ln_drift.turn_variance`).
        Floored at ``ln_sigma_floor_m``.
        """
        if ln_sigma is None:
            var = records_var(records)
            if self.config.ln_sigma_relative and len(var):
                floor2 = self.config.ln_sigma_floor_m**2
                anchor = int(np.argmax(var) if anchor_newest else np.argmin(var))
                if anchor_newest:
                    # Drift relative to the newest node, which keeps its own detection
                    # error (up to floor^2).
                    var = var.max() - var + min(var.max(), floor2)
                else:
                    # Never below min(var.min(), floor^2) >= 0: no clip needed.
                    var = var - max(var.min() - floor2, 0.0)
                if odom_cov is not None:
                    # The anchor's heading error: the alignment's rotation absorbs it.
                    var = np.maximum(var - turn_variance(xy(records), odom_cov, anchor),
                                     min(var.min(), floor2))
            sigma = np.sqrt(var)
        else:
            sigma = np.asarray(ln_sigma, dtype=float).reshape(len(records))
        return np.maximum(sigma, self.config.ln_sigma_floor_m)

    def _finite_nodes(
        self, ln: np.ndarray | RoiNetwork, ln_sigma: np.ndarray | None,
        anchor_newest: bool = False, odom_cov: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The LN nodes with finite positions: (indices into the input, 1-sigma error per
        axis, (K, 2) positions, class labels)."""
        records, kept, odom_cov = self._finite(ln, odom_cov)
        if ln_sigma is not None:
            ln_sigma = np.asarray(ln_sigma, dtype=float).reshape(len(records))[kept]
        # The nodes the matcher uses only: an ignored node must not set the least
        # uncertain node of ``ln_sigma_relative``.
        records = records[kept]
        sigma = self.node_sigma(records, ln_sigma, anchor_newest, odom_cov)
        self._judged = None
        if (anchor_newest or self.config.first_fix_judged_at_newest) and len(records):
            # The newest node: the most uncertain in the odometry's error.
            raw = records_var(records) if ln_sigma is None else np.nan_to_num(ln_sigma)
            self._judged = np.array([int(np.argmax(raw))])
        return kept, sigma, xy(records), records["label"].astype(np.int64)

    @staticmethod
    def _finite(ln: np.ndarray | RoiNetwork, odom_cov: np.ndarray | None,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """An LN's records, the indices of its nodes with finite positions, and those
        nodes' (K, 3, 3) odometry covariance (None when not given)."""
        records = as_records(ln.records if isinstance(ln, RoiNetwork) else ln)
        kept = np.flatnonzero(np.isfinite(xy(records)).all(axis=1))
        if odom_cov is not None:
            odom_cov = np.asarray(odom_cov, dtype=float).reshape(len(records), 3, 3)[kept]
        return records, kept, odom_cov

    def _tolerances(self, sigma: np.ndarray, labels: np.ndarray) -> Tolerances:
        """Tolerances, gates and weights of the finite nodes from their 1-sigma errors
        (:meth:`_finite_nodes`) and the GN's, and their per-class query plans."""
        cfg = self.config
        # d_D: node tolerance from the LN error model plus the GN position error.
        var = sigma**2 + cfg.gn_sigma_m**2
        node_tol = np.clip(cfg.n_sigma * np.sqrt(var), cfg.min_tol_m, cfg.max_tol_m)
        # Verification gate: the node tolerance, but never tighter than the fit itself is
        # known (a precise node must stay an inlier while the far ones move the fit).
        gate = np.maximum(node_tol, cfg.min_gate_m)
        groups = self.index.label_groups(labels)
        # The most precise nodes, which confirm hypotheses cheaply before the full vote.
        precise_nodes = np.argsort(node_tol, kind="stable")[: cfg.prefilter_nodes]
        precise = (precise_nodes, self.index.label_groups(labels[precise_nodes]))
        # An edge's length error is the difference of its end errors projected on it.
        edge_tol = cfg.n_sigma * np.sqrt(var[:, None] + var[None, :])
        edge_tol = np.clip(edge_tol, cfg.min_tol_m, 2 * cfg.max_tol_m)
        weights = 1.0 / (sigma**2 + cfg.gn_sigma_m**2)
        return Tolerances(node_tol, gate, edge_tol, weights, groups, precise)

    def _spread(self, pts: np.ndarray, yaw: float, covariance: np.ndarray) -> float:
        """Largest predicted 1-sigma error per axis of a node mapped by a fit, m, over
        the nodes the fit is judged at (all, or the newest: see ``_judged``)."""
        at = pts if self._judged is None else pts[self._judged]
        return float(np.sqrt(predicted_variance(at, yaw, covariance).max()))


def records_var(records: np.ndarray) -> np.ndarray:
    """Per-axis position variance of LN records from their covariance, m^2 (a missing or
    negative one as 0)."""
    var = 0.5 * (records["cov_xx"].astype(float) + records["cov_yy"].astype(float))
    return np.clip(np.nan_to_num(var), 0.0, None)
