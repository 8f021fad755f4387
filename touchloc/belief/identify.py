"""Recognition by localisation: object identity as part of the state (ch. 42.3.1)."""

from __future__ import annotations

from typing import Mapping

import numpy as np
from scipy.special import logsumexp

from .._util import as_rng, blas_threads
from .._validate import as_bool, as_mapping, as_nonnegative_float
from ..errors import BeliefDegenerateError, ValidationError
from ._common import check_contacts
from .region import PoseRegion
from .scaling_series import ScalingSeries

__all__ = ["identify", "log_evidence"]


@blas_threads
def log_evidence(model, contacts, region: PoseRegion, *, rng=None, **ss_kwargs):
    """log p(contacts | object) with a uniform pose prior over ``region``.

    Scaling Series localises the object; its final particles evenly cover the region
    of high likelihood, each standing for ``cover_volume / N`` of pose space, so

        p(D) = 1/|region| * integral p(D | X) dX ~ sum_i L_i * (cover_volume / N) / |region|

    plus the model's ``log_normalizer`` (which makes likelihoods of different objects
    comparable as densities over measurements). Returns (log evidence, belief).
    """
    # every pose, not one per class of symmetric poses: the evidence integrates over all of them
    ss = ScalingSeries(model, rng=rng, **{**ss_kwargs, "symmetry": None})
    belief = ss.localize(contacts, region)
    reg = belief.region
    ll = belief.info["log_likelihood"]
    vol = belief.info.get("cover_volume", np.nan)
    if not np.isfinite(vol) or vol <= 0:
        vol = reg.volume()
    log_z = logsumexp(ll) + np.log(vol / len(ll)) - np.log(reg.volume())
    norm = getattr(model, "log_normalizer", None)
    if callable(norm):
        log_z += norm(contacts)
    return float(log_z), belief


#: Scaling Series settings for evidence estimates: identity needs the mass of each
#: object's likelihood, not a precise pose, so the particle budget is small (and so is the
#: draw budget, 4 x the particle cap, as measured in the identification benchmark).
IDENTIFY_DEFAULTS = dict(m_per_delta=4, max_particles=3000, max_draws=12000, n_initial=1500)


@blas_threads
def identify(models: Mapping, contacts, region: PoseRegion, *, prior: Mapping | None = None, rng=None,
             return_beliefs: bool = False, **ss_kwargs):
    """Posterior probability of each object given contacts (same pose prior for all).

    Parameters
    ----------
    models : mapping name -> measurement model
        One model per candidate object (e.g. ``ProximityModel`` of each mesh, with the
        same sigmas).
    contacts : Contacts
    region : PoseRegion
        Where the object may be (uniform prior over it, whichever object it is).
    prior : mapping name -> probability, optional
        Prior over identities (uniform if None).
    return_beliefs : bool
        Also return each object's pose belief.
    **ss_kwargs
        Passed to :class:`ScalingSeries` (defaults: ``IDENTIFY_DEFAULTS``; the posterior
        stage after the last scale, ``final_moves``, is off unless beliefs are returned:
        the evidence comes from the last cover, so the stage would not change the answer).

    Returns
    -------
    dict name -> posterior probability (and a dict of beliefs when requested)

    Raises
    ------
    BeliefDegenerateError
        When no candidate explains the contacts: every candidate's belief is degenerate
        (its best pose leaves the contacts many sigma from the surface, see
        ``DEGENERATE_COST``) or has zero likelihood everywhere. Normalising such
        evidences would name one of them with probability near 1, a confident answer
        that means nothing, so none is returned.

    Examples
    --------
    >>> identify({"can": m_can, "milk": m_milk}, contacts, region, rng=0)  # doctest: +SKIP
    {'can': 0.97, 'milk': 0.03}
    """
    if not isinstance(models, Mapping) or len(models) == 0:
        raise ValidationError("models must be a non-empty mapping of name -> measurement model")
    contacts = check_contacts(contacts)
    rng = as_rng(rng)
    return_beliefs = as_bool(return_beliefs, "return_beliefs")
    if prior is not None:
        prior = as_mapping(prior, "prior", expected="a dict name -> probability")
        prior = {k: as_nonnegative_float(v, f"prior[{k!r}]") for k, v in prior.items()}
    names = list(models)
    if prior is None:
        log_prior = np.full(len(names), -np.log(len(names)))
    else:
        p = np.array([float(prior.get(n, 0.0)) for n in names])
        if np.any(p < 0) or p.sum() <= 0:
            raise ValidationError("prior must give non-negative probabilities, not all zero")
        with np.errstate(divide="ignore"):
            log_prior = np.log(p / p.sum())
    ss_kwargs = {**IDENTIFY_DEFAULTS, **({} if return_beliefs else {"final_moves": 0}), **ss_kwargs}
    log_post, beliefs = [], {}
    for name, lp in zip(names, log_prior):
        try:
            lz, b = log_evidence(models[name], contacts, region, rng=rng, **ss_kwargs)
        except BeliefDegenerateError:
            lz, b = -np.inf, None
        log_post.append(lz + lp)
        beliefs[name] = b
    log_post = np.array(log_post)
    if not np.any(np.isfinite(log_post)):
        raise BeliefDegenerateError("no candidate object explains the contacts: every likelihood underflowed")
    if all(b is None or b.degenerate for b in beliefs.values()):
        why = ", ".join(f"{n}: {_sigmas(b)}" for n, b in beliefs.items())
        raise BeliefDegenerateError(
            "no candidate object explains the contacts: at each candidate's best pose the contacts lie far "
            f"from its surface ({why}); check units (metres), the region and the candidate meshes")
    post = np.exp(log_post - logsumexp(log_post))
    out = {n: float(p) for n, p in zip(names, post)}
    return (out, beliefs) if return_beliefs else out


def _sigmas(belief) -> str:
    if belief is None:
        return "zero likelihood"
    cost = belief.info.get("mean_cost_at_map")
    return "degenerate" if cost is None else f"{np.sqrt(max(cost, 0.0)):.3g} sigma"
