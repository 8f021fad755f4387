"""``touchloc demo``: active touch localisation of a bundled mesh on a simulated table.

The mug stands at a hidden pose (x, y in a 100 mm square, any yaw). The one-step entropy
planner picks each guarded touch, the simulated world executes it, a particle filter
folds in the contact or the free space of a miss, until the belief is confident. Prints
one line per touch and writes out/demo.png and out/demo.html.
"""

from __future__ import annotations


def register(sub):
    from .planners._cli import add_arguments

    p = sub.add_parser("demo", help="active touch localisation of a bundled mesh (writes out/demo.png, .html)")
    add_arguments(p, mesh="mug", max_touches=25, particles=2000, confidence=1.5)
    p.set_defaults(func=run, name="demo")


def run(args) -> int:
    from .planners._cli import run as run_active

    return run_active(args)
