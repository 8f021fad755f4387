"""What we believe: pose regions, particle beliefs and the estimators that produce them.

Static estimators have ``localize(contacts, region) -> ParticleBelief``; filters have
``initialize(region)``, ``predict()``, ``update(contacts)`` and ``.belief``. Every filter's
``update`` also takes the executed touches of an action (a list of
``planners.TouchResult``): their contacts and the free space they swept, so any filter
can drive ``planners.active_localization``.
"""

from .._lazy import attach

#: where each public name is defined; imported on first use (see touchloc._lazy)
_NAMES = {
    "_common": ("DegenerateBeliefWarning",),
    "annealed": ("AnnealedParticleFilter", "ManifoldParticleFilter"),
    "histogram": ("HistogramFilter",),
    "identify": ("identify", "log_evidence"),
    "io": ("load_belief", "pose_to_dict", "save_belief"),
    "mcmc": ("MCMC",),
    "metrics": ("add", "add_s", "belief_coverage", "credible_level", "hpd_level", "pairwise_symmetric_distance",
        "pose_errors", "symmetric_pose_error"),
    "particle_filter": ("ParticleFilter",),
    "particles": ("RESAMPLERS", "ParticleBelief", "register_resampler", "systematic_resample"),
    "region": ("PoseRegion",),
    "scaling_series": ("ScaleStep", "ScalingSeries"),
    "smc": ("SMCFilter",),
}

__all__ = [
    "PoseRegion", "ParticleBelief", "RESAMPLERS", "register_resampler", "systematic_resample",
    "ScalingSeries", "ScaleStep", "ParticleFilter", "HistogramFilter", "AnnealedParticleFilter",
    "ManifoldParticleFilter", "SMCFilter", "MCMC", "identify", "log_evidence", "DegenerateBeliefWarning", "add_s", "add", "pose_errors",
    "symmetric_pose_error", "credible_level", "hpd_level",
    "pairwise_symmetric_distance", "belief_coverage",
    "save_belief", "load_belief", "pose_to_dict",
]

__getattr__, __dir__ = attach(__name__, _NAMES)
