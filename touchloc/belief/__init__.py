"""What we believe: pose regions, particle beliefs and the estimators that produce them."""

from .particles import RESAMPLERS, ParticleBelief, register_resampler, systematic_resample
from .region import PoseRegion

__all__ = ["PoseRegion", "ParticleBelief", "RESAMPLERS", "register_resampler", "systematic_resample"]
