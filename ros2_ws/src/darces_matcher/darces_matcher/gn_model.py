"""The GN as a search takes it (:class:`GnModel`): its index, its chance model and the
EM's outlier density, built once per GN.

The matcher holds two: the labelled one of its search, and the label-blind one of soft
semantics (step 6 of :meth:`~darces_matcher.matcher.Matcher.match`). The original DARCES
searches a label-blind one without triangle orientation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.decision import ChanceModel
from darces_matcher.em_refit import gn_density
from darces_matcher.gn_index import GnIndex
from roi_network.network import RoiNetwork

#: GN size (ROIs) up to which every triangle is indexed (the paper's exhaustive search);
#: above it, local triangles only.
EXHAUSTIVE_MAX_NODES = 300
#: GN size (ROIs) above which the local index is the smaller one (memory) and the
#: candidate cap grows with the GN.
LARGE_GN_NODES = 20000
#: Neighbours per node of a local index up to ``LARGE_GN_NODES`` ROIs (sides ~155 m at
#: 400 ROIs/km^2: consecutive route nodes ~50 m apart still make an indexed triangle;
#: with 14, under 30 % outliers 18 of 100 stressed LNs on a Poisson GN got no fix).
INDEX_NEIGHBOURS = 40
#: Neighbours per node of a local index above ``LARGE_GN_NODES`` ROIs (index memory grows
#: as neighbours^2 per node: 631 MB at 10^6 ROIs).
LARGE_GN_INDEX_NEIGHBOURS = 14
#: On a local index, control triplets whose lookup returns more candidate triangles than
#: this are not used up to ``LARGE_GN_NODES`` ROIs (an unselective triplet: on a 95 %-rock
#: GN under stress, 30,000 gave a p95 of 8.7 s and 5 of 40 LNs no fix, 3,000 0.56 s and 4).
MAX_CANDIDATES = 3000
#: The cap above ``LARGE_GN_NODES`` ROIs: at least this, and at least
#: ``LARGE_GN_CANDIDATE_SHARE`` of the GN size (the random candidates a precise triplet
#: has grow with the GN).
LARGE_GN_MAX_CANDIDATES = 30000
#: See ``LARGE_GN_MAX_CANDIDATES``.
LARGE_GN_CANDIDATE_SHARE = 0.3
#: Largest GN (ROIs) on a local index given a label-blind search too (its index doubles
#: the index memory).
LABEL_BLIND_MAX_NODES = 50000
#: The EM's class prior of the label-blind search: classes ignored.
BLIND_LABEL_CONFUSION = 0.5


@dataclass(frozen=True)
class GnModel:
    """One GN as a search takes it.

    Attributes:
        index: the triangle index and KD-trees (:class:`~darces_matcher.gn_index.GnIndex`).
        chance: what a chance alignment looks like on it (the odds decision).
        labels: (M,) its class labels.
        density: ROIs per square metre: the EM's outlier density (a node with no
            counterpart is as likely anywhere).
        label_confusion: the EM's class prior (0.5 on a label-blind model).
        use_orientation: triangles must have the same orientation (cw/ccw).
        max_candidates: the candidate cap of a control triplet on a local index.
    """

    index: GnIndex
    chance: ChanceModel
    labels: np.ndarray
    density: float
    label_confusion: float
    use_orientation: bool
    max_candidates: int

    @property
    def use_labels(self) -> bool:
        """Whether triangles, votes and odds use the class labels."""
        return self.index.use_labels


def gn_model(gn: RoiNetwork, cfg: MatchConfig, use_labels: bool) -> GnModel:
    """Build the :class:`GnModel` of a GN, labelled or label-blind.

    Raises:
        ValueError: if the GN has fewer than 3 ROIs or non-finite positions.
    """
    large = len(gn) > LARGE_GN_NODES
    index = GnIndex(
        gn, use_labels=use_labels, exhaustive_max_nodes=EXHAUSTIVE_MAX_NODES,
        neighbours=LARGE_GN_INDEX_NEIGHBOURS if large else INDEX_NEIGHBOURS,
    )
    labels = gn.records["label"].astype(np.int64)
    chance = ChanceModel(index.tree, labels, use_labels=use_labels,
                         outlier_prior=cfg.outlier_prior,
                         label_confusion=cfg.label_confusion)
    n = len(index.pts)
    max_candidates = (max(LARGE_GN_MAX_CANDIDATES, int(LARGE_GN_CANDIDATE_SHARE * n))
                      if large else MAX_CANDIDATES)
    return GnModel(index, chance, labels, gn_density(index.pts),
                   cfg.label_confusion if use_labels else BLIND_LABEL_CONFUSION,
                   not cfg.original_darces, max_candidates)


def blind_search_ok(gn: RoiNetwork, index: GnIndex) -> bool:
    """Whether a GN gets the label-blind search of soft semantics: an exhaustive index,
    or a GN of at most ``LABEL_BLIND_MAX_NODES`` ROIs."""
    return index.exhaustive or len(gn) <= LABEL_BLIND_MAX_NODES
