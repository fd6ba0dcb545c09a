"""The blackboard: which team each truck is assigned to, the idle pool, and the transfers.

Only coordinators (excavators) read and write it. A truck's entry in ``team: i32[N]`` is its team
index ``0..M-1``, ``IDLE`` (-1, in the waiting area) or ``FAILED`` (-2, broken down, never reassigned).
Transfers are resolved in team-index order, the way coordinators that take turns at the blackboard
would: team 0 recruits first, and idle trucks go out lowest index first.
"""
from __future__ import annotations

import jax.numpy as jnp

__all__ = ["IDLE", "FAILED", "membership", "team_sizes", "release", "recruit"]

IDLE = -1
FAILED = -2


def membership(team, n_teams: int):
    """``bool[M, N]``: truck k is in team i."""
    return team[None, :] == jnp.arange(n_teams, dtype=team.dtype)[:, None]


def team_sizes(team, n_teams: int):
    """``i32[M]``: trucks per team (the ``n_i`` of Eq. 1)."""
    return jnp.sum(membership(team, n_teams), axis=1).astype(jnp.int32)


def release(team, eligible, offer, want):
    """Teams with a surplus put trucks back into the idle pool, but only as many as other teams want
    beyond what the pool already holds.

    team: i32[N]; eligible: bool[N] trucks that may leave now (empty ones: driving to or queueing at
    their excavator); offer: i32[M] surplus each team could give; want: i32[M] trucks each team asks
    for. Team 0 gives first; each team gives its highest-index eligible trucks.
    Returns ``(team, released: bool[N])``.
    """
    n_teams = offer.shape[0]
    member = membership(team, n_teams) & eligible[None, :]
    offer = jnp.minimum(offer, jnp.sum(member, axis=1))
    shortfall = jnp.maximum(jnp.sum(want) - jnp.sum(team == IDLE), 0)
    before = jnp.cumsum(offer) - offer  # what lower-index teams already give
    give = jnp.clip(shortfall - before, 0, offer)
    # rank of each eligible member counted from the highest index down: 0, 1, 2, ...
    rank_desc = jnp.cumsum(member[:, ::-1], axis=1)[:, ::-1] - 1
    released = jnp.any(member & (rank_desc < give[:, None]), axis=0)
    return jnp.where(released, IDLE, team).astype(team.dtype), released


def recruit(team, want):
    """Coordinators take idle trucks, team 0 first, lowest truck index first.

    team: i32[N]; want: i32[M] (>= 0). Returns ``(team, joined: bool[N])``.
    """
    idle = team == IDLE
    rank = jnp.cumsum(idle) - 1  # position of each idle truck in the pool
    cum_want = jnp.cumsum(want)
    # the team whose share [cum_want[i-1], cum_want[i]) contains the truck's rank
    new_team = jnp.searchsorted(cum_want, rank, side="right")
    joined = idle & (rank < cum_want[-1])
    return jnp.where(joined, new_team, team).astype(team.dtype), joined
