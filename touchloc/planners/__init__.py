"""What to do next: guarded touches, candidates, simulated outcomes, lookahead planners.

>>> from touchloc.planners import GuardedTouch, OneStepPlanner
>>> plan = OneStepPlanner(model).plan(belief, candidates, rng=0)   # doctest: +SKIP
>>> plan.action, plan.scores                                       # doctest: +SKIP
"""

from .actions import (ActionCost, GuardedTouch, HandTouch, TouchResult, TravelDistance, TravelTime, as_cost,
                      fingers_of)
from .lookahead import OneStepPlanner, Plan, RandomPlanner, TwoStepPlanner
from .simulate import Outcomes, execute, simulate
from .utilities import KLDivergence, NegEntropy, TaskSuccess, Utility

__all__ = [
    "GuardedTouch", "HandTouch", "TouchResult", "ActionCost", "TravelDistance", "TravelTime", "as_cost",
    "fingers_of", "Outcomes", "simulate", "execute", "Plan", "OneStepPlanner", "TwoStepPlanner",
    "RandomPlanner", "Utility", "NegEntropy", "KLDivergence", "TaskSuccess",
]
