"""Defects found by hostile inputs, each pinned by a direct test: estimator edge cases,
NaN that used to leak out, files that are not mesh files, reflections passed as poses, and
counts so large that a call would never return."""

import math
import warnings

import numpy as np
import pytest
import trimesh

from touchloc.belief import (MCMC, AnnealedParticleFilter, HistogramFilter, ManifoldParticleFilter, ParticleBelief,
                             ParticleFilter, PoseRegion, ScalingSeries, SMCFilter, systematic_resample)
from touchloc.errors import BeliefDegenerateError, MeshError, TouchlocError, ValidationError
from touchloc.models import Contacts, IntegratedProximityModel, MeshObject, ProximityModel


@pytest.fixture(scope="module")
def box():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        obj = MeshObject(trimesh.creation.box((0.05, 0.04, 0.03)), name="box")
    model = ProximityModel(obj, 0.002, 0.1)
    pts, nrm, _ = obj.sample_surface(4, rng=0)
    return obj, model, Contacts(pts, nrm)


# -- estimators ----------------------------------------------------------------------------
@pytest.mark.parametrize("make", [
    lambda m: ParticleFilter(m, n_particles=50, rng=0),
    lambda m: AnnealedParticleFilter(m, n_particles=50, rng=0),
    lambda m: ManifoldParticleFilter(m, n_particles=50, rng=0),
    lambda m: ScalingSeries(m, rng=0),
    lambda m: HistogramFilter(m, rng=0),
], ids=["pf", "apf", "mpf", "ss", "hf"])
def test_a_region_without_free_dimensions_is_a_validation_error(box, make):
    # half_extent 0 and a fixed rotation: the particle filter divided by region.dim == 0
    obj, model, contacts = box
    region = PoseRegion.box((0, 0, 0), 0.0, np.eye(3))
    assert region.dim == 0
    with pytest.raises(ValidationError, match="no free degree of freedom"):
        make(model).localize(contacts, region)


def test_a_region_with_one_free_dimension_still_localises(box):
    obj, model, contacts = box
    region = PoseRegion.box((0, 0, 0), (0.01, 0.0, 0.0), np.eye(3))
    b = ParticleFilter(model, n_particles=50, rng=0).localize(contacts, region)
    assert region.dim == 1 and len(b) == 50 and b.resolution > 0


@pytest.mark.parametrize("bad", [-3, 0, 2.5, float("nan"), "40", None])
def test_annealed_filter_refuses_layer_counts_below_one(box, bad):
    # max_layers=-3 used to reach an UnboundLocalError inside localize
    with pytest.raises(ValidationError, match="max_layers"):
        AnnealedParticleFilter(box[1], max_layers=bad)


def test_annealed_filter_with_one_layer_runs(box):
    obj, model, contacts = box
    b = AnnealedParticleFilter(model, n_particles=50, max_layers=1, rng=0).localize(
        contacts, PoseRegion.box((0, 0, 0), 0.01, "yaw"))
    assert np.all(np.isfinite(b.log_weights[np.isfinite(b.log_weights)]))


@pytest.mark.parametrize("kwargs,match", [
    (dict(n_walkers=1), "n_walkers"), (dict(n_steps=0), "n_steps"), (dict(burn=-1), "burn"),
    (dict(thin=0), "thin"), (dict(n_steps=10, thin=11), "thin"), (dict(n_walkers=float("inf")), "n_walkers"),
])
def test_mcmc_counts_are_validated(box, kwargs, match):
    with pytest.raises(ValidationError, match=match):
        MCMC(box[1], **kwargs)


def test_mcmc_refine_from_a_start_it_cannot_use_raises_a_library_error(box):
    # a start resolution of 1e300 puts the walkers at ~1e299: the chain cannot run, and
    # what comes back is a TouchlocError, not an error from numpy's linear algebra or emcee
    obj, model, contacts = box
    region = PoseRegion.box((0, 0, 0), 0.01, "yaw")
    start = ParticleBelief(region.sample(50, rng=0), region=region, resolution=1e300)
    with pytest.raises(TouchlocError):
        MCMC(model, n_walkers=8, n_steps=5, burn=2, thin=1, rng=0).refine(contacts, start)


def test_mcmc_refine_from_a_good_start_runs(box):
    obj, model, contacts = box
    region = PoseRegion.box((0, 0, 0), 0.01, "yaw")
    start = ParticleBelief(region.sample(50, rng=0), region=region)
    b = MCMC(model, n_walkers=8, n_steps=5, burn=2, thin=1, rng=0).refine(contacts, start)
    assert np.all(np.isfinite(b.poses)) and len(b) == 8 * 5


# -- NaN that used to come back ------------------------------------------------------------
@pytest.mark.parametrize("scale", [float("nan"), float("inf"), -0.01, "0.1", None, np.array([0.1, np.nan, 0.1, 0.1])])
def test_perturb_refuses_a_scale_that_is_not_a_finite_nonnegative_number(scale):
    region = PoseRegion.box((0, 0, 0), 0.01, "full", rho=0.05)
    poses = region.sample(4, rng=0)
    with pytest.raises(ValidationError, match="scale"):
        region.perturb(poses, scale, rng=0)


def test_perturb_with_a_per_pose_scale_stays_finite():
    region = PoseRegion.box((0, 0, 0), 0.01, "full", rho=0.05)
    poses = region.sample(4, rng=0)
    out = region.perturb(poses, np.array([0.0, 0.001, 0.002, 0.003]), rng=0)
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[0], poses[0])   # a zero scale does not move the pose


@pytest.mark.parametrize("rho", [float("nan"), float("inf"), 0.0, -1.0, "0.05"])
def test_rho_must_be_a_positive_finite_length(rho):
    region = PoseRegion.box((0, 0, 0), 0.01, "full")
    with pytest.raises(ValidationError, match="rho"):
        region.with_rho(rho)
    with pytest.raises(ValidationError, match="rho"):
        PoseRegion.box((0, 0, 0), 0.01, "full", rho=rho)


def test_systematic_resample_refuses_weights_without_mass():
    with pytest.raises(BeliefDegenerateError):
        systematic_resample(np.zeros(5), 5, 0)
    with pytest.raises(ValidationError, match="weights"):
        systematic_resample(np.array([0.5, np.nan]), 2, 0)
    idx = systematic_resample(np.array([0.0, 2.0, 0.0]), 4, 0)   # unnormalised weights are fine
    assert idx.tolist() == [1, 1, 1, 1]


def test_field_helpers_say_that_nan_propagates():
    # the fuzz suite accepts NaN from exactly the callables whose docstring says so
    from touchloc.dnf import circular_convolve, diagonal_sum, sigmoid

    for fn in (sigmoid, circular_convolve, diagonal_sum):
        assert "NaN in, NaN out" in fn.__doc__
    assert math.isnan(float(sigmoid(float("nan"))))
    with pytest.raises(ValidationError, match="beta"):
        sigmoid(0.0, float("nan"))


# -- files -----------------------------------------------------------------------------------
def test_mesh_from_file_turns_every_unreadable_path_into_a_library_error(tmp_path):
    garbage = tmp_path / "garbage.obj"
    garbage.write_bytes(bytes(range(256)) * 8)          # not UTF-8: UnicodeDecodeError inside
    with pytest.raises(MeshError, match="not found"):
        MeshObject.from_file(tmp_path / "missing.obj")   # FileNotFoundError
    with pytest.raises(MeshError, match="directory"):
        MeshObject.from_file(tmp_path)                   # IsADirectoryError
    with pytest.raises(MeshError, match="could not read"):
        MeshObject.from_file(garbage)
    for bad in (True, 1, None, 1.5):                     # never a file descriptor
        with pytest.raises(ValidationError, match="must be a path"):
            MeshObject.from_file(bad)
    with pytest.raises(ValidationError, match="scale"):
        MeshObject.from_file(garbage, scale=float("nan"))


def test_mesh_from_file_reads_a_written_mesh(tmp_path):
    path = tmp_path / "box.ply"
    trimesh.creation.box((0.05, 0.04, 0.03)).export(path)
    obj = MeshObject.from_file(str(path), scale=1.0)
    assert obj.name == "box" and obj.n_faces == 12


def test_contacts_transform_refuses_reflections(box):
    contacts = box[2]
    flip = np.diag([-1.0, 1.0, 1.0, 1.0])
    with pytest.raises(ValidationError, match="det"):
        contacts.transform(flip)
    turn = np.eye(4)
    turn[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    out = contacts.transform(turn)
    np.testing.assert_allclose(out.points[:, 0], -contacts.points[:, 1])


# -- counts that would never finish ------------------------------------------------------------
def _huge_count_calls(obj, model):
    from touchloc import dnf
    from touchloc.planners import OneStepPlanner
    from touchloc.planners.candidates import CandidateGenerator, world_pool

    region = PoseRegion.box((0, 0, 0), 0.01, "yaw")
    return {
        "ParticleFilter": lambda n: ParticleFilter(model, n_particles=n),
        "ScalingSeries": lambda n: ScalingSeries(model, n_initial=n),
        "SMCFilter.moves": lambda n: SMCFilter(model, moves=n),
        "IntegratedProximityModel": lambda n: IntegratedProximityModel(obj, 0.002, n_samples=n),
        "OneStepPlanner": lambda n: OneStepPlanner(model, n_observations=n),
        "world_pool": lambda n: world_pool(region, obj, n, rng=0),
        "CandidateGenerator": lambda n: CandidateGenerator(region, obj, n_world=n),
        "generate_rotation_dataset": lambda n: dnf.generate_rotation_dataset(6, revolutions=n),
        "HistogramEstimator": lambda n: dnf.HistogramEstimator(n_bins=n),
        "Field1D": lambda n: dnf.Field1D(n),
        "MemoryTrace": lambda n: dnf.MemoryTrace(n),
        "ParticleOrientationEstimator": lambda n: dnf.ParticleOrientationEstimator(n_particles=n),
    }


@pytest.mark.parametrize("n", [10**13, 1e300])
def test_huge_counts_are_refused_before_any_work(box, n):
    obj, model, _ = box
    for name, call in _huge_count_calls(obj, model).items():
        with pytest.raises(ValidationError, match=r"must be|ask for|exceeds"):
            call(n)
