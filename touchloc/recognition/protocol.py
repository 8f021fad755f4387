"""Seed 002's evaluation protocol and the objects it is run on."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .._util import as_rng, progress_keyword
from .._util import progress as show_progress
from .._validate import as_callable, as_count, as_float_array
from ..errors import ValidationError

__all__ = ["ProtocolResult", "RejectionResult", "evaluate_protocol", "evaluate_rejection", "bundled_objects", "procedural_objects",
           "roc_auc", "roc_curve"]

#: the seven bundled meshes used as seed 002's seven objects
BUNDLED = ("bread", "can", "cereal", "lemon", "milk", "mug", "bunny")


@dataclass
class ProtocolResult:
    """Accuracy over random train/test splits (seed 002, section IV).

    Attributes
    ----------
    accuracies : (n_splits,) float
    train_times, predict_times : (n_splits,) float
        Seconds to fit, and to predict the whole test set, per split.
    n_classes, n_train, n_test : int
        Classes, and training / test sequences per class.
    """

    accuracies: np.ndarray
    train_times: np.ndarray
    predict_times: np.ndarray
    n_classes: int
    n_train: int
    n_test: int
    confusion: np.ndarray = field(repr=False, default=None)

    @property
    def mean(self) -> float:
        return float(np.mean(self.accuracies))

    @property
    def range(self) -> tuple:
        return float(np.min(self.accuracies)), float(np.max(self.accuracies))

    @property
    def chance(self) -> float:
        """Accuracy of guessing one of the classes (seed 002: 1/7, about 14 %)."""
        return 1.0 / self.n_classes


def evaluate_protocol(X, y, make_classifier, *, n_train: int = 16, n_splits: int = 10, rng=None,
                      progress=None, progress_bar=None) -> ProtocolResult:
    """Seed 002's protocol: per class, ``n_train`` sequences train and the rest test.

    Parameters
    ----------
    X : (n, T, H, W) array
    y : (n,) labels
    make_classifier : callable(split_index) -> classifier
        Returns a fresh unfitted classifier with ``fit`` and ``predict``.
    n_train : int
        Training sequences per class (seed 002: 16 of 20).
    n_splits : int
        Random partitions (seed 002: 10).
    rng : None, int or numpy.random.Generator
    progress : bool, optional
        A bar over the splits (default: when stderr is a terminal; otherwise a line to stderr every few
        seconds). ``progress_bar=`` is its deprecated old name.

    Returns
    -------
    ProtocolResult
    """
    X, y = _check_scans(X, y)
    make_classifier = as_callable(make_classifier, "make_classifier")
    n_train = as_count(n_train, "n_train", max=100_000)
    n_splits = as_count(n_splits, "n_splits", max=10_000, why="each split trains a classifier")
    progress = progress_keyword(progress, progress_bar, "evaluate_protocol")
    if len(y) != len(X):
        raise ValidationError(f"y must have one label per scan ({len(X)}), got {len(y)}")
    classes, yi = np.unique(y, return_inverse=True)
    counts = np.bincount(yi)
    if np.any(counts <= n_train):
        raise ValidationError(f"every class needs more than n_train={n_train} scans, got {dict(zip(classes.tolist(), counts.tolist()))}")
    rng = as_rng(rng)
    acc, tt, pt = [], [], []
    conf = np.zeros((len(classes), len(classes)), dtype=int)
    for s in show_progress(range(int(n_splits)), desc="splits", enabled=progress):
        train = np.zeros(len(y), dtype=bool)
        for c in range(len(classes)):
            idx = np.flatnonzero(yi == c)
            train[rng.choice(idx, size=n_train, replace=False)] = True
        clf = make_classifier(s)
        t0 = time.perf_counter()
        clf.fit(X[train], y[train])
        t1 = time.perf_counter()
        pred = clf.predict(X[~train])
        t2 = time.perf_counter()
        acc.append(float(np.mean(pred == y[~train])))
        tt.append(t1 - t0)
        pt.append(t2 - t1)
        pi = np.searchsorted(classes, pred)
        np.add.at(conf, (yi[~train], pi), 1)
    return ProtocolResult(np.array(acc), np.array(tt), np.array(pt), len(classes), int(n_train),
                          int(counts.min() - n_train), conf)


@dataclass
class RejectionResult:
    """Novelty detection on objects held back from training.

    Attributes
    ----------
    aucs : (n_splits,) float
        ROC AUC of the novelty score, known test sequences against held-back objects.
    false_reject, true_reject : (n_splits,) float
        At the classifier's calibrated threshold (None if it has none): fraction of
        known test sequences rejected, and of held-back sequences rejected.
    held_back : list of tuple
        The held-back classes of each split.
    """

    aucs: np.ndarray
    false_reject: np.ndarray | None
    true_reject: np.ndarray | None
    held_back: list


def evaluate_rejection(X, y, make_classifier, *, n_unknown: int = 2, n_train: int = 16, n_splits: int = 10,
                       rng=None) -> RejectionResult:
    """Hold ``n_unknown`` classes back, train on ``n_train`` scans of each other class.

    The classifier (from ``make_classifier(split_index)``) must have ``novelty_score``;
    if it calibrates a ``rejection_threshold_`` the rejection rates at it are reported.
    """
    X, y = _check_scans(X, y)
    make_classifier = as_callable(make_classifier, "make_classifier")
    n_unknown = as_count(n_unknown, "n_unknown")
    n_train = as_count(n_train, "n_train", max=100_000)
    n_splits = as_count(n_splits, "n_splits", max=10_000, why="each split trains a classifier")
    classes, yi = np.unique(y, return_inverse=True)
    if not 1 <= n_unknown <= len(classes) - 2:
        raise ValidationError(f"n_unknown must leave at least two known classes of {len(classes)}, got {n_unknown}")
    rng = as_rng(rng)
    aucs, fr, tr_, held = [], [], [], []
    for s in range(int(n_splits)):
        unk = rng.choice(len(classes), size=n_unknown, replace=False)
        known = ~np.isin(yi, unk)
        train = np.zeros(len(y), dtype=bool)
        for c in np.setdiff1d(np.arange(len(classes)), unk):
            idx = np.flatnonzero(yi == c)
            train[rng.choice(idx, size=min(n_train, len(idx) - 1), replace=False)] = True
        test = known & ~train
        clf = make_classifier(s).fit(X[train], y[train])
        a, b = clf.novelty_score(X[test]), clf.novelty_score(X[~known])
        aucs.append(roc_auc(a, b))
        thr = getattr(clf, "rejection_threshold_", None)
        if thr is not None:
            fr.append(float(np.mean(a > thr)))
            tr_.append(float(np.mean(b > thr)))
        held.append(tuple(classes[unk].tolist()))
    return RejectionResult(np.array(aucs), np.array(fr) if fr else None, np.array(tr_) if tr_ else None, held)


def bundled_objects() -> dict:
    """The seven bundled real meshes, by name (repair warnings silenced)."""
    from ..data import load_object

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {name: load_object(name) for name in BUNDLED}


def procedural_objects() -> dict:
    """Seven primitive shapes of similar size (5-8 cm), by name.

    Harder than the bundled set: several pairs differ only in detail (a cylinder and a
    capsule, two boxes 1 cm apart in length). Boxes differing only in height would not
    do: a pad that never reaches the table feels the same top edges (see
    docs/recognition.md).
    """
    import trimesh

    from ..models import MeshObject

    shapes = {
        "box": trimesh.creation.box(extents=(0.06, 0.05, 0.04)),
        "box_long": trimesh.creation.box(extents=(0.07, 0.05, 0.04)),
        "cylinder": trimesh.creation.cylinder(radius=0.028, height=0.05, sections=48),
        "capsule": trimesh.creation.capsule(radius=0.025, height=0.03, count=(24, 24)),
        "sphere": trimesh.creation.icosphere(subdivisions=3, radius=0.03),
        "cone": trimesh.creation.cone(radius=0.035, height=0.05, sections=48),
        "wedge": trimesh.convex.convex_hull(np.array(
            [[x, y, z] for x, y in ((0, 0), (0.07, 0), (0, 0.04)) for z in (0.0, 0.05)])),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {k: MeshObject(m, name=k) for k, m in shapes.items()}


def _check_scans(X, y):
    """Scans as the classifiers take them, and one label per scan."""
    from .classifier import _as_sequences

    X = _as_sequences(X)
    y = np.asarray(y)
    if y.ndim != 1 or len(y) != len(X):
        raise ValidationError(f"y must hold one label per scan ({len(X)},), got shape {y.shape}")
    return X, y


def _scores(x, name) -> np.ndarray:
    """(m,) novelty scores: +-inf allowed, NaN not."""
    a = as_float_array(x, name, finite=False, expected="a 1-D array of novelty scores").reshape(-1)
    if np.isnan(a).any():
        raise ValidationError(f"{name} must not contain NaN")
    return a


def roc_curve(scores_known, scores_unknown):
    """False and true positive rates of "unknown" for every threshold on a novelty score.

    Returns
    -------
    fpr, tpr : (m,) float
        Known sequences wrongly rejected, unknown sequences rightly rejected.
    """
    scores_known, scores_unknown = _scores(scores_known, "scores_known"), _scores(scores_unknown, "scores_unknown")
    s = np.concatenate([scores_known, scores_unknown])
    lab = np.concatenate([np.zeros(len(scores_known)), np.ones(len(scores_unknown))])
    order = np.argsort(-s, kind="mergesort")
    s, lab = s[order], lab[order]
    tp = np.cumsum(lab)
    fp = np.cumsum(1 - lab)
    last = np.r_[np.flatnonzero(np.diff(s)), len(s) - 1]
    tpr = np.r_[0.0, tp[last] / max(lab.sum(), 1)]
    fpr = np.r_[0.0, fp[last] / max((1 - lab).sum(), 1)]
    return fpr, tpr


def roc_auc(scores_known, scores_unknown) -> float:
    """Area under the ROC of a novelty score (0.5 = chance, 1 = perfect separation)."""
    a = _scores(scores_known, "scores_known")[:, None]
    b = _scores(scores_unknown, "scores_unknown")[None, :]
    if a.size == 0 or b.size == 0:
        raise ValidationError("roc_auc needs at least one known and one unknown score")
    return float(np.mean((b > a) + 0.5 * (b == a)))
