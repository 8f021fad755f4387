"""Seed 002's protocol, ROC helpers, object sets and the `touchloc recognize` command."""

import numpy as np
import pytest

from touchloc.cli import main
from touchloc.errors import ValidationError
from touchloc.models import MeshObject
from touchloc.recognition import (NearestNeighbourClassifier, evaluate_protocol, evaluate_rejection,
                                  procedural_objects, roc_auc, roc_curve)


def _toy(n_per_class=6, n_classes=3, seed=0):
    """Separable toy sequences (n, 4, 4, 4): one bright texel per class."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, 50, (n_per_class * n_classes, 4, 4, 4))
    y = np.repeat(np.arange(n_classes), n_per_class)
    for c in range(n_classes):
        X[y == c, c, 1 + c % 2, 1] += 3000.0
    return X, y


class _Recorder(NearestNeighbourClassifier):
    sizes = []

    def fit(self, X, y):
        _Recorder.sizes.append(np.bincount(np.asarray(y)).tolist())
        return super().fit(X, y)


def test_protocol_splits_per_class_and_reports_accuracy():
    X, y = _toy()
    _Recorder.sizes = []
    r = evaluate_protocol(X, y, lambda s: _Recorder(align=False), n_train=4, n_splits=3, rng=0)
    assert _Recorder.sizes == [[4, 4, 4]] * 3
    assert r.accuracies.shape == (3,) and r.mean == 1.0 and r.range == (1.0, 1.0)
    assert r.chance == pytest.approx(1 / 3)
    assert r.n_test == 2 and r.confusion.sum() == 3 * 3 * 2
    assert np.all(r.train_times >= 0) and np.all(r.predict_times >= 0)
    with pytest.raises(ValidationError, match="more than n_train"):
        evaluate_protocol(X, y, lambda s: _Recorder(), n_train=6)


def test_rejection_protocol_holds_classes_back():
    X, y = _toy(n_classes=4)
    r = evaluate_rejection(X, y, lambda s: NearestNeighbourClassifier(align=False, reject_quantile=0.9),
                           n_unknown=1, n_train=4, n_splits=3, rng=0)
    assert r.aucs.shape == (3,) and len(r.held_back) == 3
    assert r.aucs.min() > 0.9  # a new bright texel is far from every training sequence
    assert r.true_reject is not None and r.true_reject.mean() > 0.5


def test_numeric_labels_are_rejected_as_minus_one():
    X, y = _toy(n_classes=3)
    known = y < 2
    clf = NearestNeighbourClassifier(align=False, reject_quantile=0.9).fit(X[known], y[known])
    pred = clf.predict(X[~known], reject=True)
    assert pred.dtype.kind == "i" and np.all(pred == -1)
    assert set(clf.predict(X[known], reject=True).tolist()) <= {-1, 0, 1}


def test_roc_auc_and_curve():
    assert roc_auc([0, 1, 2], [3, 4]) == 1.0
    assert roc_auc([3, 4], [0, 1, 2]) == 0.0
    assert roc_auc([1, 1], [1, 1]) == 0.5
    rng = np.random.default_rng(0)
    a, b = rng.normal(0, 1, 200), rng.normal(1, 1, 150)
    fpr, tpr = roc_curve(a, b)
    assert fpr[0] == tpr[0] == 0 and fpr[-1] == tpr[-1] == 1
    assert np.all(np.diff(fpr) >= 0) and np.all(np.diff(tpr) >= 0)
    assert np.trapezoid(tpr, fpr) == pytest.approx(roc_auc(a, b), abs=1e-12)
    # two unit Gaussians 1 sigma apart: AUC = Phi(1/sqrt(2)) = 0.76
    assert roc_auc(a, b) == pytest.approx(0.76, abs=0.06)
    with pytest.raises(ValidationError):
        roc_auc([], [1.0])


def test_procedural_objects():
    objs = procedural_objects()
    assert len(objs) == 7
    for name, o in objs.items():
        assert isinstance(o, MeshObject) and o.name == name
        assert 0.03 < o.extents.max() < 0.09


def test_recognize_command(capsys, tmp_path):
    png = tmp_path / "scan.png"
    rc = main(["recognize", "--objects", "procedural", "--scans", "3", "--train", "2", "--splits", "1",
               "--no-baseline", "--plot", str(png)])
    out = capsys.readouterr().out
    assert rc == 0
    assert "SequenceClassifier (6, 8, 20, svd)" in out and "chance 14 %" in out
    assert png.stat().st_size > 1000
    assert main(["recognize", "--scans", "4", "--train", "4"]) == 1
    assert "must exceed" in capsys.readouterr().err
