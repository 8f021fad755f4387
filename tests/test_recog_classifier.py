"""Seed 002's view-based classifier: alignment, AEV, Sanger's rule, LLM, end to end."""

import warnings

import numpy as np
import pytest
import trimesh

from touchloc.errors import TouchlocError, ValidationError
from touchloc.models import MeshObject
from touchloc.recognition import (LocalLinearMap, NearestNeighbourClassifier, NotFittedError,
                                  SequenceClassifier, aev_quantize, align_sequences,
                                  sanger_pca, simulate_dataset, svd_pca)


@pytest.fixture(scope="module")
def two_shapes():
    """8 scans each of a box and a sphere (full 160-frame scans)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        objs = {"box": MeshObject(trimesh.creation.box(extents=(0.06, 0.05, 0.04)), name="box"),
                "sphere": MeshObject(trimesh.creation.icosphere(subdivisions=3, radius=0.03), name="sphere"),
                "cone": MeshObject(trimesh.creation.cone(radius=0.035, height=0.05, sections=32), name="cone")}
    X, y = simulate_dataset(objs, 8, rng=11)
    return X, y


def _split(y, n_train, rng):
    train = np.zeros(len(y), dtype=bool)
    for c in np.unique(y):
        idx = np.flatnonzero(y == c)
        train[rng.choice(idx, n_train, replace=False)] = True
    return train


def test_two_clearly_different_shapes_are_separated(two_shapes):
    X, y = two_shapes
    keep = y != "cone"
    X, y = X[keep], y[keep]
    train = _split(y, 6, np.random.default_rng(0))
    for clf in (SequenceClassifier(rng=0), SequenceClassifier(pca="sanger", sanger_epochs=100, rng=0),
                NearestNeighbourClassifier()):
        clf.fit(X[train], y[train])
        assert clf.predict(X[~train]).tolist() == y[~train].tolist(), clf
    s = SequenceClassifier(rng=0).fit(X[train], y[train]).predict_scores(X[~train])
    assert s.shape == (4, 2)
    # the winning output is close to the one-hot target, not a near tie
    assert np.all(s.max(axis=1) - s.min(axis=1) > 0.5)


def test_rejection_flags_an_object_not_trained_on(two_shapes):
    X, y = two_shapes
    known = y != "cone"
    train = known & _split(y, 6, np.random.default_rng(1))
    # 12 training scans support one cell (the defaults would leave 2 scans per cell)
    clf = SequenceClassifier(n_vq=1, n_pc=4, reject_quantile=0.95, rng=0).fit(X[train], y[train])
    assert clf.rejection_threshold_ is not None
    nov_known = clf.novelty_score(X[known & ~train])
    nov_cone = clf.novelty_score(X[~known])
    assert np.all((nov_known >= 0) & (nov_known <= 1))
    assert nov_cone.min() > nov_known.max()
    pred = clf.predict(X[~known], reject=True)
    assert np.mean(pred == "unknown") >= 0.75
    assert set(clf.predict(X[~known]).tolist()) <= {"box", "sphere"}  # without reject: forced choice
    with pytest.raises(NotFittedError, match="reject_quantile"):
        SequenceClassifier(n_vq=2, rng=0).fit(X[train], y[train]).predict(X[:1], reject=True)


def test_sanger_converges_to_the_leading_components_of_a_known_covariance():
    rng = np.random.default_rng(5)
    d, k = 8, 3
    Q, _ = np.linalg.qr(rng.standard_normal((d, d)))
    lam = np.array([6.0, 3.0, 1.5, 0.4, 0.3, 0.2, 0.1, 0.05])
    Z = rng.standard_normal((4000, d)) * np.sqrt(lam) @ Q.T
    W = sanger_pca(Z - Z.mean(axis=0), k, epochs=20, rng=1, space="input")
    # rows: unit length, in eigenvalue order, aligned with the true eigenvectors (up to
    # sign); with 4000 samples the sample eigenvectors are within ~0.03 rad of the truth
    assert np.allclose(np.linalg.norm(W, axis=1), 1.0, atol=0.02)
    cos = np.abs(np.einsum("kd,dk->k", W, Q[:, :k]))
    assert np.all(cos > 0.99), cos


def test_sanger_in_sample_space_matches_the_svd_subspace():
    # fewer samples than dimensions (the seed's situation, d = 40960): coefficient space
    rng = np.random.default_rng(2)
    Z = rng.standard_normal((25, 3)) * np.array([5.0, 2.0, 1.0]) @ rng.standard_normal((3, 500))
    Z += 0.05 * rng.standard_normal(Z.shape)
    Zc = Z - Z.mean(axis=0)
    W = sanger_pca(Zc, 3, epochs=400, rng=0)
    V = svd_pca(Zc, 3)
    assert np.allclose(np.abs(np.einsum("kd,kd->k", W, V)), 1.0, atol=0.01)


def test_svd_pca_pads_beyond_the_rank():
    Zc = np.array([[1.0, 0, 0, 0], [-1.0, 0, 0, 0]])
    W = svd_pca(Zc, 3)
    assert np.allclose(np.abs(W[0]), [1, 0, 0, 0]) and not np.any(W[1:])


def test_activity_equalisation_uses_every_reference():
    rng = np.random.default_rng(0)
    centres = np.array([[0, 0], [10, 0], [0, 10], [10, 10]], float)
    Z = np.repeat(centres, 25, axis=0) + 0.3 * rng.standard_normal((100, 2))
    truth = np.repeat(np.arange(4), 25)
    for seed in range(5):
        refs, lab = aev_quantize(Z, 4, rng=seed)
        # one reference per cluster: every cluster maps to exactly one reference
        assert len(np.unique(lab)) == 4
        assert all(len(np.unique(lab[truth == c])) == 1 for c in range(4))


def test_local_linear_map_fits_a_piecewise_linear_function():
    rng = np.random.default_rng(0)
    P = rng.uniform(-1, 1, (400, 1))
    T = np.abs(P)  # two linear pieces
    llm = LocalLinearMap(4, ridge=1e-6, rng=0).fit(P, T)
    Q = np.linspace(-0.9, 0.9, 50)[:, None]
    assert np.max(np.abs(llm.predict(Q) - np.abs(Q))) < 0.1


def test_alignment_centres_the_whole_sequence():
    X = np.zeros((2, 5, 16, 16))
    X[0, :, 2:4, 3:5] = 100.0  # a blob off centre
    X[1] = np.roll(X[0], (6, 5), axis=(1, 2))
    X[0, 2, 2, 3] = 300.0
    X[1, 2, 8, 8] = 300.0
    A = align_sequences(X)
    assert np.array_equal(A[0], A[1])
    tot = A[0].sum(axis=0)
    r = (tot.sum(axis=1) @ np.arange(16)) / tot.sum()
    assert abs(r - 7.5) <= 0.5
    blank = align_sequences(np.zeros((1, 3, 16, 16)))
    assert not blank.any()


def test_predict_before_fit_is_a_clear_error():
    for clf in (SequenceClassifier(), NearestNeighbourClassifier()):
        with pytest.raises(NotFittedError, match="fit"):
            clf.predict(np.zeros((1, 160, 16, 16)))
        with pytest.raises(TouchlocError):
            clf.predict_scores(np.zeros((1, 160, 16, 16)))


def test_wrong_inputs_say_what_was_expected(two_shapes):
    X, y = two_shapes
    clf = SequenceClassifier(rng=0)
    with pytest.raises(ValidationError, match=r"\(n_scans, n_frames, rows, cols\)"):
        clf.fit(X[0], y[:1])
    with pytest.raises(ValidationError, match="y must be"):
        clf.fit(X, y[:-1])
    with pytest.raises(ValidationError, match="two classes"):
        clf.fit(X[:3], y[:3])
    bad = X[:4].astype(float)
    bad[1, 5, 2, 2] = np.nan
    with pytest.raises(ValidationError, match="scan 1"):
        clf.fit(bad, y[:4])
    with pytest.raises(ValidationError, match="n_vq"):
        SequenceClassifier(n_vq=0)
    with pytest.raises(ValidationError, match="pca"):
        SequenceClassifier(pca="eig")
    clf.fit(X, y)
    with pytest.raises(ValidationError, match="like the training data"):
        clf.predict(X[:, :80])
