"""What we believe: pose regions, particle beliefs and the estimators that produce them.

Static estimators have ``localize(contacts, region) -> ParticleBelief``; filters have
``initialize(region)``, ``predict()``, ``update(contacts)`` and ``.belief``. Every filter's
``update`` also takes the executed touches of an action (a list of
``planners.TouchResult``): their contacts and the free space they swept, so any filter
can drive ``planners.active_localization``.
"""

from ._common import DegenerateBeliefWarning
from .annealed import AnnealedParticleFilter, ManifoldParticleFilter
from .histogram import HistogramFilter
from .identify import identify, log_evidence
from .io import load_belief, pose_to_dict, save_belief
from .mcmc import MCMC
from .metrics import (add, add_s, belief_coverage, credible_level, hpd_level, pairwise_symmetric_distance, pose_errors,
                      symmetric_pose_error)
from .particle_filter import ParticleFilter
from .particles import RESAMPLERS, ParticleBelief, register_resampler, systematic_resample
from .region import PoseRegion
from .scaling_series import ScaleStep, ScalingSeries
from .smc import SMCFilter

__all__ = [
    "PoseRegion", "ParticleBelief", "RESAMPLERS", "register_resampler", "systematic_resample",
    "ScalingSeries", "ScaleStep", "ParticleFilter", "HistogramFilter", "AnnealedParticleFilter",
    "ManifoldParticleFilter", "SMCFilter", "MCMC", "identify", "log_evidence", "DegenerateBeliefWarning", "add_s", "add", "pose_errors",
    "symmetric_pose_error", "credible_level", "hpd_level",
    "pairwise_symmetric_distance", "belief_coverage",
    "save_belief", "load_belief", "pose_to_dict",
]
