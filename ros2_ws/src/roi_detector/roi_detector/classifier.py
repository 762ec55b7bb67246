"""The paper's binary ROI classifiers (Sec. 4.3): standardisation, PCA, k-nearest neighbours
(and, as an alternative, gradient-boosted trees).

One :class:`BinaryClassifier` per class and imagery ("Rock Orbital", "Outcrop Orbital",
"Rock Rover", "Outcrop Rover"), built on scikit-learn. A set of them is saved as one
``.npz`` file of plain arrays plus a JSON provenance string (training seeds, feature names,
library versions): no pickle, so loading a model file runs no code. A kNN model *is* its
training set, so the file stores the training features and labels and loading re-fits the
(deterministic) pipeline on them. A boosted-tree model is stored as its trees
(:class:`TreeEnsemble`: the scaler and every node as plain arrays, evaluated here in
numpy), so its size does not grow with the training set; files of the first format, which
stored the training set of the trees too, still load (re-fitted).
"""

from __future__ import annotations

import json
import os
import platform
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Final

import numpy as np
import sklearn
from scipy.special import expit
from sklearn.decomposition import PCA
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.neighbors import KNeighborsClassifier
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from threadpoolctl import threadpool_limits

MODEL_FORMAT: Final = "globloc-roi-classifiers/2"
#: Formats :func:`load_classifiers` reads (/1: boosted trees stored as their training set).
READABLE_FORMATS: Final = ("globloc-roi-classifiers/1", MODEL_FORMAT)


class ModelFileError(ValueError):
    """A model file is missing, unreadable or inconsistent; the message names the file."""


@dataclass(frozen=True)
class ClassifierConfig:
    """Hyper-parameters of one binary classifier.

    Attributes:
        n_components: PCA dimensions kept (capped by the feature and sample counts).
        k: neighbours voting.
        weights: ``"uniform"`` (the paper's plain vote) or ``"distance"``.
        kind: ``"knn"`` (the paper's: standardise, PCA, kNN) or ``"gradient_boosting"``
            (not the paper's: scikit-learn's histogram gradient boosting on the standardised
            features, classes weighted by their inverse frequency, fixed seed; for
            candidate sets where true ROIs are a few percent).
    """

    n_components: int = 8
    k: int = 5
    weights: str = "uniform"
    kind: str = "knn"

    def __post_init__(self) -> None:
        if self.kind not in ("knn", "gradient_boosting"):
            raise ValueError(f"ClassifierConfig.kind: {self.kind!r} not knn/gradient_boosting")


@dataclass(frozen=True)
class TreeEnsemble:
    """A fitted binary gradient-boosted tree ensemble (after standardisation) as plain
    arrays, evaluated in numpy exactly as scikit-learn's histogram gradient boosting
    evaluates it (same float operations in the same order; tested to equality).

    Attributes:
        mean, scale: the standardisation (``(x - mean) / scale`` on float32 features).
        baseline: the raw score before any tree (log-odds of the weighted prior).
        roots: (T,) global index of each tree's root node, in boosting order.
        value: (M,) raw score of a leaf (shrinkage included).
        feature: (M,) feature index a split node tests.
        threshold: (M,) a split goes left when the feature is <= this.
        missing_left: (M,) a NaN feature goes left.
        left, right: (M,) global indices of a split node's children.
        is_leaf: (M,).
    """

    mean: np.ndarray
    scale: np.ndarray
    baseline: float
    roots: np.ndarray
    value: np.ndarray
    feature: np.ndarray
    threshold: np.ndarray
    missing_left: np.ndarray
    left: np.ndarray
    right: np.ndarray
    is_leaf: np.ndarray

    #: Each field's dtype in memory (to_arrays stores the index fields as int32).
    DTYPES: ClassVar[dict[str, type]] = {
        "mean": np.float64, "scale": np.float64, "baseline": np.float64,
        "roots": np.int64, "value": np.float64, "feature": np.int64,
        "threshold": np.float64, "missing_left": bool, "left": np.int64,
        "right": np.int64, "is_leaf": bool}

    @classmethod
    def _typed(cls, **fields: Any) -> TreeEnsemble:
        out = {k: np.asarray(fields[k]).astype(t) for k, t in cls.DTYPES.items()}
        out["baseline"] = float(out["baseline"])
        return cls(**out)

    @classmethod
    def from_pipeline(cls, pipeline: Pipeline) -> TreeEnsemble:
        """The trees of a fitted ``StandardScaler -> HistGradientBoostingClassifier``."""
        scaler, gbt = pipeline.named_steps["scale"], pipeline.named_steps["gbt"]
        if gbt.n_trees_per_iteration_ != 1:
            raise ValueError("TreeEnsemble: binary classifiers only")
        nodes, roots, start = [], [], 0
        for (pred,) in gbt._predictors:
            n = pred.nodes
            if n["is_categorical"].any():
                raise ValueError("TreeEnsemble: categorical splits are not supported")
            roots.append(start)
            nodes.append((n, start))
            start += n.size
        cat = np.concatenate([n for n, _ in nodes])
        off = np.concatenate([np.full(n.size, o, np.int64) for n, o in nodes])
        return cls._typed(mean=scaler.mean_, scale=scaler.scale_,
                          baseline=np.ravel(gbt._baseline_prediction)[0], roots=roots,
                          value=cat["value"], feature=cat["feature_idx"],
                          threshold=cat["num_threshold"],
                          missing_left=cat["missing_go_to_left"],
                          left=cat["left"].astype(np.int64) + off,
                          right=cat["right"].astype(np.int64) + off, is_leaf=cat["is_leaf"])

    def raw_score(self, x: np.ndarray) -> np.ndarray:
        """(N,) raw score (log-odds) of float32 features ``x`` (N, F)."""
        z = np.array(x, dtype=np.float32)  # the scaler's in-place float32 arithmetic
        z -= self.mean
        z /= self.scale
        z = z.astype(np.float64)
        raw = np.full(z.shape[0], self.baseline)
        rows = np.arange(z.shape[0])
        for root in self.roots:
            node = np.full(z.shape[0], root)
            active = ~self.is_leaf[node]
            while active.any():
                nd = node[active]
                v = z[rows[active], self.feature[nd]]
                go_left = np.where(np.isnan(v), self.missing_left[nd], v <= self.threshold[nd])
                node[active] = np.where(go_left, self.left[nd], self.right[nd])
                active = ~self.is_leaf[node]
            raw += self.value[node]
        return raw

    def predict_proba(self, x: np.ndarray) -> np.ndarray:
        """(N,) probability of the class (the logistic of the raw score)."""
        return expit(self.raw_score(x))

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """The fields as arrays named ``prefix + field`` (indices as int32)."""
        small = {"roots", "feature", "left", "right"}
        return {f"{prefix}{k}": np.asarray(getattr(self, k)).astype(np.int32) if k in small
                else np.asarray(getattr(self, k)) for k in self.DTYPES}

    @classmethod
    def from_arrays(cls, data: dict[str, np.ndarray], prefix: str) -> TreeEnsemble:
        """Inverse of :meth:`to_arrays`; raises KeyError or ValueError when inconsistent."""
        a = {k: data[f"{prefix}{k}"] for k in cls.DTYPES}
        m = a["value"].size
        for k in ("feature", "threshold", "missing_left", "left", "right", "is_leaf"):
            if a[k].shape != (m,):
                raise ValueError(f"tree field {k!r} has shape {a[k].shape}, expected ({m},)")
        split = ~a["is_leaf"].astype(bool)
        if m == 0 or a["roots"].size == 0 or (a["roots"] < 0).any() or (a["roots"] >= m).any() \
                or (split & ((a["left"] < 0) | (a["left"] >= m) | (a["right"] < 0)
                             | (a["right"] >= m)
                             | (a["feature"] < 0) | (a["feature"] >= a["mean"].size))).any():
            raise ValueError("tree node indices out of range")
        return cls._typed(**a)


@dataclass
class BinaryClassifier:
    """Standardise -> PCA -> kNN (or boosted trees), deciding "is this candidate of the
    class" (1) or not (0).

    Attributes:
        name: e.g. ``"rock_orbital"``.
        feature_names: names of the feature vector entries, in order.
        config: hyper-parameters.
    """

    name: str
    feature_names: tuple[str, ...]
    config: ClassifierConfig = field(default_factory=ClassifierConfig)
    _x: np.ndarray | None = None
    _y: np.ndarray | None = None
    _pipeline: Pipeline | None = None
    _trees: TreeEnsemble | None = None
    _n_samples: int = 0
    _n_positive: int = 0

    def fit(self, x: np.ndarray, y: np.ndarray) -> BinaryClassifier:
        """Train on (N, F) features ``x`` and (N,) 0/1 labels ``y``.

        Raises:
            ValueError: on shape mismatch, non-finite features, or a single class.
        """
        x = np.asarray(x, dtype=np.float32)
        y = np.asarray(y).astype(np.uint8)
        if x.ndim != 2 or x.shape[1] != len(self.feature_names):
            raise ValueError(f"{self.name}: features must be (N, {len(self.feature_names)}), "
                             f"got {x.shape}")
        if y.shape != (x.shape[0],):
            raise ValueError(f"{self.name}: labels must be ({x.shape[0]},), got {y.shape}")
        if not np.isfinite(x).all():
            raise ValueError(f"{self.name}: training features hold non-finite values")
        # The model file stores the training set as float16 (half the size): train on that
        # precision here too, so that a loaded model is the very one that was saved.
        x = _half(x).astype(np.float32)
        if len(np.unique(y)) < 2:
            raise ValueError(f"{self.name}: training labels need both classes, got only "
                             f"{np.unique(y).tolist()} ({len(y)} samples)")
        if self.config.kind == "gradient_boosting":
            # One OpenMP thread: on a shared machine, scikit-learn's default (all cores)
            # made this 30x slower under contention; the fit is small.
            with threadpool_limits(1):
                pipeline = Pipeline([
                    ("scale", StandardScaler()),
                    ("gbt", HistGradientBoostingClassifier(
                        max_iter=200, learning_rate=0.1, class_weight="balanced",
                        early_stopping=False, random_state=0)),
                ]).fit(x, y)
            # The trees are the model (what is saved and what predicts): a loaded model
            # runs the very code a fresh one does.
            self._trees = TreeEnsemble.from_pipeline(pipeline)
            self._n_samples, self._n_positive = int(y.size), int(y.sum())
            return self
        else:
            n_comp = max(1, min(self.config.n_components, x.shape[1], x.shape[0] - 1))
            k = max(1, min(self.config.k, x.shape[0]))
            self._pipeline = Pipeline([
                ("scale", StandardScaler()),
                ("pca", PCA(n_components=n_comp, svd_solver="full")),
                ("knn", KNeighborsClassifier(n_neighbors=k, weights=self.config.weights)),
            ]).fit(x, y)
        self._x, self._y = x, y
        self._n_samples, self._n_positive = int(y.size), int(y.sum())
        return self

    @classmethod
    def from_trees(cls, name: str, feature_names: tuple[str, ...], config: ClassifierConfig,
                   trees: TreeEnsemble, n_samples: int, n_positive: int) -> BinaryClassifier:
        """A boosted-tree classifier from its stored trees (no training set)."""
        if trees.mean.size != len(feature_names):
            raise ValueError(f"{name}: trees read {trees.mean.size} features, "
                             f"{len(feature_names)} names")
        clf = cls(name, tuple(feature_names), config)
        clf._trees, clf._n_samples, clf._n_positive = trees, n_samples, n_positive
        return clf

    @property
    def is_fitted(self) -> bool:
        return self._pipeline is not None or self._trees is not None

    def predict_proba(self, x: np.ndarray) -> np.ndarray:
        """(N,) probability in [0, 1] that each candidate is of the class (kNN: vote share)."""
        if not self.is_fitted:
            raise RuntimeError(f"{self.name}: classifier is not trained")
        x = np.asarray(x, dtype=np.float32)
        if x.shape[0] == 0:
            return np.zeros(0, np.float64)
        if x.ndim != 2 or x.shape[1] != len(self.feature_names):
            raise ValueError(f"{self.name}: features must be (N, {len(self.feature_names)}), "
                             f"got {x.shape}")
        # Non-finite features (degenerate candidate) vote "not of the class".
        ok = np.isfinite(x).all(axis=1)
        proba = np.zeros(x.shape[0], np.float64)
        if ok.any() and self._trees is not None:
            proba[ok] = self._trees.predict_proba(x[ok])
        elif ok.any():
            classes = list(self._pipeline.classes_)
            with threadpool_limits(1):
                proba[ok] = self._pipeline.predict_proba(x[ok])[:, classes.index(1)]
        return proba

    def predict(self, x: np.ndarray, threshold: float = 0.5) -> np.ndarray:
        """(N,) bool: probability above ``threshold``."""
        return self.predict_proba(x) > threshold


def _half(x: np.ndarray) -> np.ndarray:
    """float16 copy, clipped to its finite range."""
    lim = np.finfo(np.float16).max
    return np.clip(x, -lim, lim).astype(np.float16)


def library_versions() -> dict[str, str]:
    """Versions of what a model's behaviour depends on."""
    import cv2
    import scipy
    import skimage
    return {"python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "scikit-learn": sklearn.__version__,
            "scikit-image": skimage.__version__, "opencv": cv2.__version__}


def save_classifiers(path: str | os.PathLike[str], classifiers: dict[str, BinaryClassifier],
                     provenance: dict[str, Any]) -> None:
    """Write classifiers and provenance to one ``.npz`` (no pickle), atomically.

    Args:
        path: output file (``.npz``).
        classifiers: trained classifiers by name.
        provenance: JSON-serialisable facts (training bags and seeds, recipe, ...);
            feature names, hyper-parameters and library versions are added here.
    """
    arrays: dict[str, np.ndarray] = {}
    meta: dict[str, Any] = {"format": MODEL_FORMAT, "provenance": provenance,
                            "library_versions": library_versions(), "classifiers": {}}
    for name, clf in classifiers.items():
        if clf._trees is not None:
            arrays.update(clf._trees.to_arrays(f"{name}__trees_"))
        elif clf._x is not None and clf._y is not None:
            arrays[f"{name}__x"] = _half(clf._x)
            arrays[f"{name}__y"] = clf._y
        else:
            raise ValueError(f"save_classifiers: classifier '{name}' is not trained")
        meta["classifiers"][name] = {
            "feature_names": list(clf.feature_names),
            "config": {"n_components": clf.config.n_components, "k": clf.config.k,
                       "weights": clf.config.weights, "kind": clf.config.kind},
            "stored": "trees" if clf._trees is not None else "training set",
            "n_samples": clf._n_samples, "n_positive": clf._n_positive,
        }
    arrays["meta_json"] = np.frombuffer(json.dumps(meta, sort_keys=True).encode(), np.uint8)
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(path)


def load_classifiers(path: str | os.PathLike[str]) -> tuple[dict[str, BinaryClassifier],
                                                           dict[str, Any]]:
    """Read a file written by :func:`save_classifiers` (``allow_pickle=False``).

    Returns:
        (classifiers by name, metadata dict with ``provenance`` and ``library_versions``).

    Raises:
        ModelFileError: naming the file and what is wrong with it.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"model file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:  # zipfile, OSError, ValueError: all mean "not a model file"
        raise ModelFileError(f"{path}: not a readable .npz model file ({exc})") from exc
    if "meta_json" not in data:
        raise ModelFileError(f"{path}: field 'meta_json' is missing")
    try:
        meta = json.loads(bytes(data["meta_json"].astype(np.uint8)).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelFileError(f"{path}: field 'meta_json' is not JSON ({exc})") from exc
    if meta.get("format") not in READABLE_FORMATS:
        raise ModelFileError(f"{path}: format {meta.get('format')!r}, expected one of "
                             f"{list(READABLE_FORMATS)}")
    out = {}
    for name, info in meta.get("classifiers", {}).items():
        try:
            config = ClassifierConfig(**info["config"])
            if f"{name}__trees_value" in data:
                clf = BinaryClassifier.from_trees(
                    name, tuple(info["feature_names"]), config,
                    TreeEnsemble.from_arrays(data, f"{name}__trees_"),
                    int(info["n_samples"]), int(info["n_positive"]))
            else:
                x, y = data[f"{name}__x"], data[f"{name}__y"]
                clf = BinaryClassifier(name, tuple(info["feature_names"]), config)
                clf.fit(x, y)
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFileError(f"{path}: classifier '{name}' is invalid ({exc})") from exc
        out[name] = clf
    return out, meta
