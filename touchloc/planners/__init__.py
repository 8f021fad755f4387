"""What to do next: guarded touches, candidates, simulated outcomes, lookahead planners."""

from .actions import GuardedTouch, HandTouch, TouchResult

__all__ = ["GuardedTouch", "HandTouch", "TouchResult"]
