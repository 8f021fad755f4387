"""What to do next: guarded touches, candidates, simulated outcomes, lookahead planners.

>>> from touchloc.planners import GuardedTouch, OneStepPlanner
>>> plan = OneStepPlanner(model).plan(belief, candidates, rng=0)   # doctest: +SKIP
>>> plan.action, plan.scores                                       # doctest: +SKIP
"""

from .actions import (ActionCost, GuardedTouch, HandTouch, TouchResult, TravelDistance, TravelTime, as_cost,
                      fingers_of)
from .candidates import CandidateGenerator, hand_pool, relative_pool, world_pool
from .identity import IdentityPlanner
from .lookahead import OneStepPlanner, Plan, RandomPlanner, TwoStepPlanner
from .loop import ActiveResult, SimulatedWorld, Step, active_localization
from .metrics import add_s, best_pose, expected_add_s, prob_error_below
from .scenarios import Scenario, make_scenario
from .simulate import Outcomes, execute, simulate
from .utilities import KLDivergence, NegEntropy, TaskSuccess, Utility

__all__ = [
    "GuardedTouch", "HandTouch", "TouchResult", "ActionCost", "TravelDistance", "TravelTime", "as_cost",
    "fingers_of", "Outcomes", "simulate", "execute", "Plan", "OneStepPlanner", "TwoStepPlanner",
    "RandomPlanner", "Utility", "NegEntropy", "KLDivergence", "TaskSuccess", "CandidateGenerator",
    "world_pool", "relative_pool", "hand_pool", "active_localization", "SimulatedWorld", "ActiveResult", "Step",
    "add_s", "best_pose", "expected_add_s", "prob_error_below", "Scenario", "make_scenario", "IdentityPlanner",
]

_DEPRECATED = {"TouchFilter": "touchloc.belief.SMCFilter", "TouchLikelihood": "touchloc.models.TouchLikelihood",
               "EstimatorUpdater": "a touchloc.belief filter as active_localization's updater"}


def __getattr__(name):
    # old names of the estimator and the touch likelihood, importable for one more release
    if name in _DEPRECATED:
        import warnings

        from . import update

        warnings.warn(f"touchloc.planners.{name} is deprecated and will be removed in the next release; use "
                      f"{_DEPRECATED[name]}", DeprecationWarning, stacklevel=2)
        return getattr(update, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
