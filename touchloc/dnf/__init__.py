"""Dynamic neural fields and the orientation tracker of seed 000.

A rotating object's orientation and shape (its flat sides) are estimated from contact
normals and the hand's odometry: :class:`OrientationTracker` implements the model of
seed 000 (Fig. 2), :func:`count_surfaces` its rule for counting sides. The baselines of
seed 000, section V (:class:`HistogramEstimator`, the tracker with ``correct=False``), a
Rao-Blackwellised particle filter (:class:`ParticleOrientationEstimator`), a generator of
the seed's experiment and a loader for recorded data complete the comparison.
"""

from .._lazy import attach

#: where each public name is defined; imported on first use (see touchloc._lazy)
_NAMES = {
    "data": ("OBJECTS", "SEED_FAITHFUL", "RotationDataset", "generate_rotation_dataset", "load_recording",
        "save_recording", "standard_datasets"),
    "estimators": ("HistogramEstimator", "count_surfaces", "normalize_max", "surface_peaks"),
    "fields": ("Field1D", "Field2D", "FieldParams", "MemoryTrace", "circular_convolve", "diagonal_sum", "expand",
        "lateral_inputs", "lateral_kernel", "sigmoid"),
    "tracker": ("OrientationTracker", "TrackerParams", "contact_spreads", "population_code"),
    "particle": ("ParticleOrientationEstimator",),
    "compare": ("EstimatorRun", "compare", "default_estimators", "orientation_error", "run_estimator",
        "summary_table"),
}

__all__ = [
    "OrientationTracker", "TrackerParams", "count_surfaces", "surface_peaks", "HistogramEstimator",
    "normalize_max", "population_code", "contact_spreads", "ParticleOrientationEstimator",
    "compare", "run_estimator", "default_estimators", "orientation_error", "summary_table", "EstimatorRun",
    "Field1D", "Field2D", "FieldParams", "MemoryTrace", "sigmoid", "lateral_kernel", "circular_convolve",
    "lateral_inputs", "expand", "diagonal_sum",
    "RotationDataset", "generate_rotation_dataset", "standard_datasets", "load_recording", "save_recording",
    "OBJECTS", "SEED_FAITHFUL",
]

__getattr__, __dir__ = attach(__name__, _NAMES)
