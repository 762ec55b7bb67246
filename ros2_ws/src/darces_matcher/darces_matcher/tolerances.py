"""Steps 1-2 of :meth:`~darces_matcher.matcher.Matcher.match`: the LN's nodes as the search
takes them, and their tolerances d_D, gates and weights from the LN error model.

Each LN node with a finite position gets a 1-sigma position error per axis
(:func:`node_sigma`: from the records' covariance, relative to an anchor node, floored;
:func:`ln_nodes`), and where a fit of the LN is judged precise (the newest node, where
the rover is). With the GN's error the sigma sets the node tolerance d_D, the
verification gate, the edge tolerance of a triangle and the node's weight in a fit
(:func:`tolerances`).
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

#: Smallest node tolerance in the edge tolerance d_D, metres.
MIN_TOL_M = 1.0
#: Smallest verification gate, metres: tighter, and the precise nodes drop out when the
#: far ones move the fit; looser, random votes.
MIN_GATE_M = 2.5
#: Largest node tolerance, metres (caps far, drifted nodes).
MAX_TOL_M = 30.0
#: The most precise LN nodes that may confirm a hypothesis before the full vote.
PREFILTER_NODES = 8


@dataclass(frozen=True)
class LnNodes:
    """Step 1's outcome: an LN's nodes with finite positions, in input order.

    Attributes:
        kept: (K,) indices of those nodes into the input records.
        records: (K,) their records (:data:`~roi_network.records.ROI_DTYPE`), ``odom``.
        sigma: (K,) 1-sigma position error per axis of each node, metres.
        pts: (K, 2) positions, ``odom``, metres.
        labels: (K,) class labels.
        judged: indices (into the K nodes) of the nodes a fit is judged precise at
            (``max_position_sigma_m``): the newest node; None: every node.
        odom_cov: (K, 3, 3) odometry (x, y, yaw) covariance each node was observed with
            when the sigmas come from the records, else None.
    """

    kept: np.ndarray
    records: np.ndarray
    sigma: np.ndarray
    pts: np.ndarray
    labels: np.ndarray
    judged: np.ndarray | None
    odom_cov: np.ndarray | None

    def __len__(self) -> int:
        return len(self.kept)


@dataclass(frozen=True)
class Tolerances:
    """Step 2's outcome for the finite nodes of an LN, in their order.

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


def node_sigma(records: np.ndarray, ln_sigma: np.ndarray | None, floor_m: float,
               anchor_newest: bool = False,
               odom_cov: np.ndarray | None = None) -> np.ndarray:
    """1-sigma position error per axis of each LN node, metres.

    From ``ln_sigma`` when given, else from the records' covariance (cov_xx, cov_yy)
    relative to the least uncertain node (to the most uncertain one, the newest, with
    ``anchor_newest``). An LN placed by odometry carries, at every node, the error the
    odometry had accumulated before the LN began: an offset and a turn common to all its
    nodes, which the alignment absorbs; only the growth beyond the anchor's variance
    (less ``floor_m``^2, kept as the anchor's own detection error) tells the nodes apart.
    With ``odom_cov``, the (K, 3, 3) odometry (x, y, yaw) covariance each node was
    observed with, what the anchor's heading error explains is taken off too
    (:func:`~darces_matcher.ln_drift.turn_variance`). Floored at ``floor_m``.
    """
    if ln_sigma is None:
        var = records_var(records)
        if len(var):
            floor2 = floor_m**2
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
    return np.maximum(sigma, floor_m)


def finite_records(ln: np.ndarray | RoiNetwork, odom_cov: np.ndarray | None,
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """An LN's records, the indices of its nodes with finite positions, and those
    nodes' (K, 3, 3) odometry covariance (None when not given)."""
    records = as_records(ln.records if isinstance(ln, RoiNetwork) else ln)
    kept = np.flatnonzero(np.isfinite(xy(records)).all(axis=1))
    if odom_cov is not None:
        odom_cov = np.asarray(odom_cov, dtype=float).reshape(len(records), 3, 3)[kept]
    return records, kept, odom_cov


def ln_nodes(ln: np.ndarray | RoiNetwork, ln_sigma: np.ndarray | None, cfg: MatchConfig,
             anchor_newest: bool = False, odom_cov: np.ndarray | None = None) -> LnNodes:
    """Step 1: the LN nodes with finite positions and their error model.

    Args:
        ln: LN records (:data:`~roi_network.records.ROI_DTYPE`) or network, ``odom``.
        ln_sigma: optional (N,) 1-sigma position error per axis of each LN node, metres;
            default: from the records' covariance (:func:`node_sigma`).
        cfg: the matcher's settings (the sigma floor; the original DARCES judges a fit
            at every node unless ``anchor_newest``).
        anchor_newest: the records' covariance is taken relative to the newest node.
        odom_cov: optional (N, 3, 3) odometry (x, y, yaw) covariance of each node.
    """
    records, kept, odom_cov = finite_records(ln, odom_cov)
    if ln_sigma is not None:
        ln_sigma = np.asarray(ln_sigma, dtype=float).reshape(len(records))[kept]
        odom_cov = None
    # The nodes the matcher uses only: an ignored node must not set the anchor.
    records = records[kept]
    sigma = node_sigma(records, ln_sigma, cfg.ln_sigma_floor_m, anchor_newest, odom_cov)
    judged = None
    if (anchor_newest or not cfg.original_darces) and len(records):
        # The newest node, where the rover is and where the fix places it: the most
        # uncertain in the odometry's error.
        raw = records_var(records) if ln_sigma is None else np.nan_to_num(ln_sigma)
        judged = np.array([int(np.argmax(raw))])
    return LnNodes(kept, records, sigma, xy(records), records["label"].astype(np.int64),
                   judged, odom_cov)


def tolerances(nodes: LnNodes, index: GnIndex, cfg: MatchConfig) -> Tolerances:
    """Step 2: tolerances, gates and weights of the finite nodes from their 1-sigma
    errors and the GN's, and their per-class query plans on ``index``."""
    sigma, labels = nodes.sigma, nodes.labels
    # d_D: node tolerance from the LN error model plus the GN position error.
    var = sigma**2 + cfg.gn_sigma_m**2
    node_tol = np.clip(cfg.n_sigma * np.sqrt(var), MIN_TOL_M, MAX_TOL_M)
    # Verification gate: the node tolerance, but never tighter than the fit itself is
    # known (a precise node must stay an inlier while the far ones move the fit).
    gate = np.maximum(node_tol, MIN_GATE_M)
    groups = index.label_groups(labels)
    # The most precise nodes, which confirm hypotheses cheaply before the full vote.
    precise_nodes = np.argsort(node_tol, kind="stable")[:PREFILTER_NODES]
    precise = (precise_nodes, index.label_groups(labels[precise_nodes]))
    # An edge's length error is the difference of its end errors projected on it.
    edge_tol = cfg.n_sigma * np.sqrt(var[:, None] + var[None, :])
    edge_tol = np.clip(edge_tol, MIN_TOL_M, 2 * MAX_TOL_M)
    weights = 1.0 / (sigma**2 + cfg.gn_sigma_m**2)
    return Tolerances(node_tol, gate, edge_tol, weights, groups, precise)


def fit_spread(nodes: LnNodes, yaw: float, covariance: np.ndarray) -> float:
    """Largest predicted 1-sigma error per axis of a node mapped by a fit, metres, over
    the nodes the fit is judged at (:attr:`LnNodes.judged`)."""
    at = nodes.pts if nodes.judged is None else nodes.pts[nodes.judged]
    return float(np.sqrt(predicted_variance(at, yaw, covariance).max()))


def records_var(records: np.ndarray) -> np.ndarray:
    """Per-axis position variance of LN records from their covariance, m^2 (a missing or
    negative one as 0)."""
    var = 0.5 * (records["cov_xx"].astype(float) + records["cov_yy"].astype(float))
    return np.clip(np.nan_to_num(var), 0.0, None)
