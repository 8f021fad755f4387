"""Tactile object identification from sequences of pressure images (seed 002).

* :class:`TactileScanner` and :func:`simulate_dataset` simulate seed 002's scans: a
  16 x 16 pressure pad lowered onto an object, tilted about its leading contact and
  rolled around the object, 160 frames at 10 Hz.
* :class:`SequenceClassifier` is seed 002's view-based classifier (alignment, activity-
  equalising vector quantisation, local PCA, local linear maps), with an optional
  rejection of unknown objects; :class:`NearestNeighbourClassifier` is the baseline.
* :func:`evaluate_protocol` runs seed 002's protocol (16 train / 4 test scans per object,
  10 random splits).

>>> from touchloc.recognition import SequenceClassifier
>>> clf = SequenceClassifier()           # n_vq=6, n_pc=8, n_llm=20 as in seed 002
"""

from .._lazy import attach

#: where each public name is defined; imported on first use (see touchloc._lazy)
_NAMES = {
    "classifier": ("LocalLinearMap", "NearestNeighbourClassifier", "NotFittedError", "SequenceClassifier",
        "aev_quantize", "align_sequences", "sanger_pca", "svd_pca"),
    "plot": ("plot_scan",),
    "protocol": ("ProtocolResult", "RejectionResult", "bundled_objects", "evaluate_protocol", "evaluate_rejection",
        "procedural_objects", "roc_auc", "roc_curve"),
    "simulate": ("PadConfig", "Scan", "TactileScanner", "simulate_dataset"),
}

__all__ = [
    "SequenceClassifier", "NearestNeighbourClassifier", "NotFittedError", "LocalLinearMap",
    "align_sequences", "aev_quantize", "sanger_pca", "svd_pca",
    "TactileScanner", "PadConfig", "Scan", "simulate_dataset",
    "evaluate_protocol", "ProtocolResult", "evaluate_rejection", "RejectionResult", "bundled_objects", "procedural_objects",
    "roc_auc", "roc_curve", "plot_scan",
]

__getattr__, __dir__ = attach(__name__, _NAMES)
