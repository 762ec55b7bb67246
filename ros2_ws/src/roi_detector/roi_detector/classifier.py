"""The paper's binary ROI classifiers (Sec. 4.3): standardisation, PCA, k-nearest neighbours
(and, as an alternative, gradient-boosted trees).

One :class:`BinaryClassifier` per class and imagery ("Rock Orbital", "Outcrop Orbital",
"Rock Rover", "Outcrop Rover"), built on scikit-learn. A set of them is saved as one
``.npz`` file of plain arrays plus a JSON provenance string (training seeds, feature names,
library versions): no pickle, so loading a model file runs no code. A kNN model *is* its
training set, so the file stores the training features and labels and loading re-fits the
(deterministic: fixed seed) pipeline on them; the same holds for the boosted trees.
"""

from __future__ import annotations

import json
import os
import platform
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import sklearn
from sklearn.decomposition import PCA
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.neighbors import KNeighborsClassifier
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from threadpoolctl import threadpool_limits

MODEL_FORMAT: Final = "globloc-roi-classifiers/1"


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
                self._pipeline = Pipeline([
                    ("scale", StandardScaler()),
                    ("gbt", HistGradientBoostingClassifier(
                        max_iter=200, learning_rate=0.1, class_weight="balanced",
                        early_stopping=False, random_state=0)),
                ]).fit(x, y)
        else:
            n_comp = max(1, min(self.config.n_components, x.shape[1], x.shape[0] - 1))
            k = max(1, min(self.config.k, x.shape[0]))
            self._pipeline = Pipeline([
                ("scale", StandardScaler()),
                ("pca", PCA(n_components=n_comp, svd_solver="full")),
                ("knn", KNeighborsClassifier(n_neighbors=k, weights=self.config.weights)),
            ]).fit(x, y)
        self._x, self._y = x, y
        return self

    @property
    def is_fitted(self) -> bool:
        return self._pipeline is not None

    def predict_proba(self, x: np.ndarray) -> np.ndarray:
        """(N,) probability in [0, 1] that each candidate is of the class (kNN: vote share)."""
        if self._pipeline is None:
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
        if ok.any():
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
        if clf._x is None or clf._y is None:
            raise ValueError(f"save_classifiers: classifier '{name}' is not trained")
        arrays[f"{name}__x"] = _half(clf._x)
        arrays[f"{name}__y"] = clf._y
        meta["classifiers"][name] = {
            "feature_names": list(clf.feature_names),
            "config": {"n_components": clf.config.n_components, "k": clf.config.k,
                       "weights": clf.config.weights, "kind": clf.config.kind},
            "n_samples": int(clf._y.size), "n_positive": int(clf._y.sum()),
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
    if meta.get("format") != MODEL_FORMAT:
        raise ModelFileError(f"{path}: format {meta.get('format')!r}, expected {MODEL_FORMAT}")
    out = {}
    for name, info in meta.get("classifiers", {}).items():
        try:
            x, y = data[f"{name}__x"], data[f"{name}__y"]
            clf = BinaryClassifier(name, tuple(info["feature_names"]),
                                   ClassifierConfig(**info["config"]))
            clf.fit(x, y)
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFileError(f"{path}: classifier '{name}' is invalid ({exc})") from exc
        out[name] = clf
    return out, meta
