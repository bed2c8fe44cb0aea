"""Where a turning frame's second pass is measured: on the master, or on the members that measured its
patches, chosen by what each has cost (pure; :class:`services.master.refine.MemberRefine` wires it).

The second pass's crops travel raw (frame k turned back), so whether sending them pays depends on the link
and the CPUs: at 1920x1080 (48 patches of 128 px) it saved one master about 40 ms of CPU a turning frame,
and on a CPU three times faster, over 100 Mbit, it made the turning frames 26 % slower than one host alone
(the members' raw crops are 0.4-0.5 MB a frame; docs/methods.md). A fixed size threshold cannot tell these
apart, so each place's cost is measured as the wall time of a whole pass per refined patch (sent: until the
last part is back, the master's own part measured meanwhile), kept as a running mean, and the cheaper place
is taken. The other place is measured again every ``probe_every`` passes, so that a link or a load that
changes is noticed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import Enum

from common.bounds import Bounded, bounded
from common.errors import InputError


class RefinePlace(Enum):
    """Where a pass is measured."""

    HERE = "here"
    MEMBERS = "members"


@dataclass(frozen=True)
class RefinePlaceSettings(Bounded):
    """How the place is chosen."""

    #: weight of the newest pass in each place's running mean cost
    memory: float = bounded(0.3, gt=0.0, le=1.0)
    #: the place not taken is measured again after this many passes
    probe_every: int = bounded(16, ge=2)


@dataclass(frozen=True)
class RefineCosts:
    """Each place's running mean cost in seconds of wall time per refined patch (NaN: not measured yet), and
    how many passes ran since the place not taken was last measured."""

    here_s_per_patch: float = math.nan
    members_s_per_patch: float = math.nan
    since_probe: int = 0

    def cheaper(self) -> RefinePlace | None:
        """The place that has cost less so far (None: one of them not measured yet)."""
        here, members = self.here_s_per_patch, self.members_s_per_patch
        if math.isnan(here) or math.isnan(members):
            return None
        return RefinePlace.HERE if here <= members else RefinePlace.MEMBERS


def choose_place(costs: RefineCosts, settings: RefinePlaceSettings) -> RefinePlace:
    """The members until they have been measured (they are what the cluster is for), then the master until
    it has been; after that the cheaper place, and the other one every ``probe_every`` passes."""
    if math.isnan(costs.members_s_per_patch):
        return RefinePlace.MEMBERS
    if math.isnan(costs.here_s_per_patch):
        return RefinePlace.HERE
    cheaper = costs.cheaper()
    if costs.since_probe + 1 >= settings.probe_every:
        return RefinePlace.MEMBERS if cheaper is RefinePlace.HERE else RefinePlace.HERE
    return RefinePlace.HERE if cheaper is None else cheaper


def _mean(previous: float, value: float, memory: float) -> float:
    return value if math.isnan(previous) else (1.0 - memory) * previous + memory * value


def observe_pass(
    costs: RefineCosts,
    settings: RefinePlaceSettings,
    place: RefinePlace,
    patches: int,
    seconds: float,
    here_patches: int = 0,
    here_seconds: float = 0.0,
) -> RefineCosts:
    """``costs`` after a pass of ``patches`` at ``place`` that took ``seconds``; a pass sent to the members
    whose ``here_patches`` the master measured itself in ``here_seconds`` (its part) gives the master's cost
    its first figure when it has none yet."""
    if patches < 1 or not (math.isfinite(seconds) and seconds >= 0.0):
        raise InputError(f"a pass needs >= 1 patch and a finite time >= 0, got {patches}, {seconds}")
    if here_patches < 0 or not (math.isfinite(here_seconds) and here_seconds >= 0.0):
        raise InputError(f"the master's part needs >= 0 patches, a time >= 0: {here_patches}, {here_seconds}")
    cheaper = costs.cheaper()
    memory = settings.memory
    per_patch = seconds / patches
    if place is RefinePlace.HERE:
        updated = replace(costs, here_s_per_patch=_mean(costs.here_s_per_patch, per_patch, memory))
    else:
        updated = replace(costs, members_s_per_patch=_mean(costs.members_s_per_patch, per_patch, memory))
        if here_patches > 0 and math.isnan(costs.here_s_per_patch):
            # the master's part, measured while the members worked: a first figure of what it costs alone
            updated = replace(updated, here_s_per_patch=here_seconds / here_patches)
    probed = cheaper is not None and place is not cheaper
    return replace(updated, since_probe=0 if probed else costs.since_probe + 1)


__all__ = ["RefineCosts", "RefinePlace", "RefinePlaceSettings", "choose_place", "observe_pass"]
