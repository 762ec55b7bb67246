"""Step 6 of :meth:`~darces_matcher.matcher.Matcher.match`: soft semantics.

Labels are hard where they are cheap and selective (control triplets, hypotheses, votes)
and soft where a misclassified node would otherwise be lost: when the labelled search
gives no fix, the LN is searched again blind to classes (on the label-blind
:class:`~darces_matcher.gn_model.GnModel`), and that fix is kept only if its inliers
mostly agree on class (a class-swapped LN finds its geometric match but fails this
check). The EM refit's class prior (``label_confusion``) lets misclassified nodes join a
labelled fix softly.
"""

from __future__ import annotations

import numpy as np

from darces_matcher.result import MatchResult
from darces_matcher.tolerances import LnNodes

#: Least share of a label-blind fix's inlier pairs whose LN and GN classes agree.
MIN_LABEL_AGREEMENT = 0.75
#: Reasons of a labelled no-fix that a label-blind search cannot change.
FINAL_REASONS = ("too_few_nodes", "no_control_triplet")


def label_blind_outcome(labelled: MatchResult, blind: MatchResult, nodes: LnNodes,
                        gn_labels: np.ndarray) -> MatchResult:
    """An LN's outcome after its label-blind search: the blind fix (reason
    ``"ok_label_blind"``) when its inliers mostly agree on class, else the labelled
    no-fix (reason ``"label_mismatch"`` when the blind fix's classes disagree).

    Args:
        labelled: the labelled search's no-fix.
        blind: the label-blind search's outcome.
        nodes: the LN's nodes (step 1).
        gn_labels: (M,) the GN's class labels.
    """
    for stage, ms in blind.timings_ms.items():
        key = "total" if stage == "total" else f"blind_{stage}"
        labelled.timings_ms[key] = labelled.timings_ms.get(key, 0.0) + ms
    if not blind.is_fix:
        return labelled
    rows = np.searchsorted(nodes.kept, blind.inliers[:, 0])
    agree = float(np.mean(nodes.labels[rows] == gn_labels[blind.inliers[:, 1]]))
    if agree < MIN_LABEL_AGREEMENT:
        labelled.reason = "label_mismatch"
        return labelled
    blind.reason = "ok_label_blind"
    blind.timings_ms = labelled.timings_ms
    blind.n_triplets += labelled.n_triplets
    blind.n_hypotheses += labelled.n_hypotheses
    return blind
