"""What to do next: guarded touches, candidates, simulated outcomes, lookahead planners."""

from .actions import GuardedTouch, HandTouch

__all__ = ["GuardedTouch", "HandTouch"]
