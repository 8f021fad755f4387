"""What to do next: guarded touches, candidates, simulated outcomes, lookahead planners.

>>> from touchloc.planners import GuardedTouch, OneStepPlanner
>>> plan = OneStepPlanner(model).plan(belief, candidates, rng=0)   # doctest: +SKIP
>>> plan.action, plan.scores                                       # doctest: +SKIP
"""

from .._lazy import attach

#: where each public name is defined; imported on first use (see touchloc._lazy)
_NAMES = {
    "actions": ("ActionCost", "GuardedTouch", "HandTouch", "TouchResult", "TravelDistance", "TravelTime",
        "as_cost", "fingers_of"),
    "candidates": ("CandidateGenerator", "hand_pool", "relative_pool", "world_pool"),
    "identity": ("IdentityPlanner",),
    "lookahead": ("OneStepPlanner", "Plan", "RandomPlanner", "TwoStepPlanner"),
    "loop": ("ActiveResult", "SimulatedWorld", "Step", "active_localization"),
    "metrics": ("add_s", "best_pose", "expected_add_s", "prob_error_below"),
    "scenarios": ("Scenario", "make_scenario"),
    "simulate": ("Outcomes", "execute", "simulate"),
    "utilities": ("KLDivergence", "NegEntropy", "TaskSuccess", "Utility"),
}

__all__ = [
    "GuardedTouch", "HandTouch", "TouchResult", "ActionCost", "TravelDistance", "TravelTime", "as_cost",
    "fingers_of", "Outcomes", "simulate", "execute", "Plan", "OneStepPlanner", "TwoStepPlanner",
    "RandomPlanner", "Utility", "NegEntropy", "KLDivergence", "TaskSuccess", "CandidateGenerator",
    "world_pool", "relative_pool", "hand_pool", "active_localization", "SimulatedWorld", "ActiveResult", "Step",
    "add_s", "best_pose", "expected_add_s", "prob_error_below", "Scenario", "make_scenario", "IdentityPlanner",
]

_DEPRECATED = {"TouchFilter": "touchloc.belief.SMCFilter", "TouchLikelihood": "touchloc.models.TouchLikelihood",
               "EstimatorUpdater": "a touchloc.belief filter as active_localization's updater"}


def _deprecated(name):
    # old names of the estimator and the touch likelihood, importable for one more release
    if name in _DEPRECATED:
        import warnings

        from . import update

        warnings.warn(f"touchloc.planners.{name} is deprecated and will be removed in the next release; use "
                      f"{_DEPRECATED[name]}", DeprecationWarning, stacklevel=3)
        return getattr(update, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__getattr__, __dir__ = attach(__name__, _NAMES, fallback=_deprecated)
