import numpy as np
import pytest
import trimesh

from touchloc.belief import ParticleBelief
from touchloc.errors import PlanningError
from touchloc.models import MeshObject
from touchloc.planners import GuardedTouch, IdentityPlanner


@pytest.fixture(scope="module")
def two_boxes():
    short = MeshObject(trimesh.creation.box(extents=(0.1, 0.1, 0.1)), name="short")
    tall = MeshObject(trimesh.creation.box(extents=(0.1, 0.1, 0.2)), name="tall")
    return {"short": short, "tall": tall}


def test_the_touch_that_tells_objects_apart_is_chosen(two_boxes):
    here = {n: ParticleBelief(np.eye(4)[None], rho=0.05) for n in two_boxes}  # pose known, identity not
    cands = [
        GuardedTouch((0.3, 0, 0.0), (-1, 0, 0), 0.5),   # hits both at the same place: useless
        GuardedTouch((0.3, 0, 0.08), (-1, 0, 0), 0.5),  # above the short box: hits the tall one only
        GuardedTouch((0, 0, 0.3), (0, 0, -1), 0.5),     # from above: stops 5 cm apart
    ]
    plan = IdentityPlanner(two_boxes).plan(here, {"short": 0.5, "tall": 0.5}, cands, rng=0)
    H = plan.details["expected_entropy"]
    assert H[0] == pytest.approx(np.log(2), abs=0.02)
    assert H[1] < 0.1 and H[2] < 0.1
    assert plan.index in (1, 2)
    # when the identity is already known, no touch can tell more
    sure = IdentityPlanner(two_boxes).plan(here, {"short": 1.0, "tall": 0.0}, cands, rng=0)
    assert np.allclose(sure.details["expected_entropy"], 0.0)


def test_identity_planner_rejects_bad_candidates(two_boxes):
    here = {n: ParticleBelief(np.eye(4)[None], rho=0.05) for n in two_boxes}
    with pytest.raises(PlanningError, match="GuardedTouch"):
        IdentityPlanner(two_boxes).plan(here, {"short": 0.5, "tall": 0.5}, [], rng=0)
