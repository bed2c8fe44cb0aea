"""The capacity model (:mod:`common.capacity`): streams a fleet carries from one stream's measured cost."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.capacity import Fleet, Resource, StreamCost, predict
from common.errors import InputError

costs = st.builds(
    StreamCost,
    fps=st.floats(1.0, 60.0),
    ground_cpu_ms=st.floats(0.1, 50.0),
    member_cpu_ms=st.floats(0.1, 500.0),
    ground_bytes=st.floats(0.0, 5e6),
    member_bytes=st.floats(0.0, 5e6),
    source_cpu_ms=st.floats(0.0, 5.0),
    worker_cpu_ms=st.floats(0.0, 400.0),
    workers_per_frame=st.integers(1, 8),
)
fleets = st.builds(
    Fleet,
    hosts=st.integers(1, 20),
    cores_per_host=st.floats(1.0, 64.0),
    ground_cores=st.floats(1.0, 64.0),
    link_bit_s=st.one_of(st.none(), st.floats(1e6, 1e10)),
)


@settings(max_examples=100, deadline=None)
@given(cost=costs, fleet=fleets)
def test_the_limiting_resource_carries_the_streams_within_its_ceiling_and_one_more_breaks_it(
    cost: StreamCost, fleet: Fleet
) -> None:
    p = predict(cost, fleet)
    for resource, use in p.use_per_stream.items():
        assert use * p.streams <= fleet.max_utilisation * (1 + 1e-9), resource
    assert p.use_per_stream[p.limited_by] * (p.streams + 1) > fleet.max_utilisation
    assert p.path_ms >= 0.0 and math.isfinite(p.path_ms)
    assert p.streams <= p.streams_exact + 1e-6 and p.streams_exact < p.streams + 1


@settings(max_examples=100, deadline=None)
@given(cost=costs, fleet=fleets, more=st.integers(1, 10), faster=st.floats(1.0, 10.0))
def test_more_hosts_cores_or_bandwidth_never_carry_fewer_streams(
    cost: StreamCost, fleet: Fleet, more: int, faster: float
) -> None:
    base = predict(cost, fleet).streams
    bigger = [
        Fleet(fleet.hosts + more, fleet.cores_per_host, fleet.ground_cores, fleet.link_bit_s),
        Fleet(fleet.hosts, fleet.cores_per_host * faster, fleet.ground_cores * faster, fleet.link_bit_s),
    ]
    if fleet.link_bit_s is not None:
        bigger.append(Fleet(fleet.hosts, fleet.cores_per_host, fleet.ground_cores, fleet.link_bit_s * faster))
    for grown in bigger:
        assert predict(cost, grown).streams >= base, grown


def test_a_shared_pool_divides_its_cores_by_every_process_cost() -> None:
    """Two cores at 80 %, 20 fps, 10 + 25 + 5 ms a frame: 1.6 / 0.8 = 2 streams."""
    cost = StreamCost(fps=20.0, ground_cpu_ms=10.0, member_cpu_ms=25.0, ground_bytes=0.0, member_bytes=0.0,
                      source_cpu_ms=5.0)  # fmt: skip
    p = predict(cost, Fleet(hosts=2, cores_per_host=1.0, ground_cores=1.0, shared_cores=2.0))
    assert (p.streams, p.limited_by) == (2, Resource.SHARED_CPU)
    assert p.use_per_stream[Resource.SHARED_CPU] == pytest.approx(0.4)


def test_the_ground_link_limits_a_fleet_whose_frames_are_large() -> None:
    """3 MB out per frame at 1 fps is 24 Mbit/s: a 100 Mbit link at 80 % carries 3 streams."""
    cost = StreamCost(fps=1.0, ground_cpu_ms=10.0, member_cpu_ms=70.0, ground_bytes=3e6, member_bytes=3e6)
    p = predict(cost, Fleet(hosts=10, cores_per_host=16.0, ground_cores=16.0, link_bit_s=1e8))
    assert (p.streams, p.limited_by) == (3, Resource.GROUND_LINK)


@pytest.mark.parametrize(
    "make",
    [
        lambda: StreamCost(fps=0.0, ground_cpu_ms=1.0, member_cpu_ms=1.0, ground_bytes=0.0, member_bytes=0.0),
        lambda: StreamCost(fps=20, ground_cpu_ms=math.nan, member_cpu_ms=1, ground_bytes=0, member_bytes=0),
        lambda: StreamCost(fps=20, ground_cpu_ms=-1.0, member_cpu_ms=1, ground_bytes=0, member_bytes=0),
        lambda: Fleet(hosts=0, cores_per_host=1.0, ground_cores=1.0),
        lambda: Fleet(hosts=1, cores_per_host=1.0, ground_cores=1.0, link_bit_s=0.0),
        lambda: Fleet(hosts=1, cores_per_host=1.0, ground_cores=1.0, max_utilisation=1.5),
        lambda: predict(
            StreamCost(fps=20, ground_cpu_ms=0, member_cpu_ms=0, ground_bytes=0, member_bytes=0),
            Fleet(hosts=1, cores_per_host=1.0, ground_cores=1.0),
        ),
    ],
)
def test_bad_inputs_are_one_clear_error(make: object) -> None:
    with pytest.raises(InputError):
        make()  # type: ignore[operator]
