"""``capataz bench dispatch``: CPU time per frame by role, from /proc readings around a flight."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.dispatch import SELF
from common.errors import CapatazError
from common.members import Topology
from common.yaw import YawSettings
from services.camera import CameraSettings, simulated_flight
from services.camera.settings import FlightName
from services.runtime.allocator import HeapPolicy
from services.tools.bench.dispatch import (
    ALONE,
    PATHS,
    ROLES,
    add_arguments,
    cluster_path,
    cpu_ms_per_frame,
    heap_label,
    host_cpus,
    path_spec,
    run,
    summary_table,
)
from services.tools.bench.dispatch_workload import TURNS_FROM_FRAME, flight_frames, workload_of
from services.tools.netns import unavailable_reason
from tests.zenoh_helpers import members_outweigh_master

seconds = st.floats(0.0, 100.0, allow_nan=False)

#: members' smallest deadline in the flights below: the frame's whole budget
GENEROUS_DEADLINE = ("--min-deadline-ms", "1000")


def _bench_args(out: Path, *argv: str) -> argparse.Namespace:
    """The bench's options as its parser gives them (its defaults, one home), ``out`` the output folder."""
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(argv)
    args.out = out
    return args


def test_the_table_gives_medians_over_the_repeats_and_the_master_s_share_of_the_in_process_median() -> None:
    def flight(master_ms: float, worker_ms: float, tx_bytes: float) -> dict[str, Any]:
        cpu = {"master": master_ms, "foreman": 0.0, "worker": worker_ms, "router": 0.1}
        return {
            "frames": 10,
            "lost": 0,
            "cpu_ms_per_frame": cpu,
            "links": {"h1": {"tx_bytes_per_frame": tx_bytes}},
        }

    runs = {"master-worker 1": [flight(2.0, 9.0, 1e3), flight(9.0, 10.0, 3e3), flight(3.0, 11.0, 2e3)]}
    for run_, frame_ms in zip(runs["master-worker 1"], (40.0, 90.0, 50.0), strict=True):
        run_["median_timings_ms"] = {"total": frame_ms, "round": frame_ms / 2}
    table = summary_table([10.0, 12.0, 8.0], 27, runs)
    assert table[0]["in_process_ms"] == 10.0 and table[0]["frames"] == 27
    row = table[1]
    assert row["master_ms"] == 3.0 and row["worker_ms"] == 10.0 and row["frames"] == 30
    assert row["master_share"] == pytest.approx(0.3) and 0.3 < row["master_share_p95"] <= 0.9
    assert 3.0 < row["master_ms_p95"] <= 9.0
    assert row["h1_tx_kB"] == pytest.approx(2.0)  # the mean over the repeats
    assert row["frame_ms"] == 50.0  # the master's frame time, median over the repeats
    assert row["latency_ratio"] == pytest.approx(5.0)  # against the in-process median, 10 ms
    # each repeat against its own in-process run (4, 7.5, 6.25): a drift of the shared host cancels out
    assert row["paired_ratio"] == pytest.approx(6.25)
    assert "vs_alone" not in row  # the master alone did not fly


def test_a_path_against_the_master_alone_is_the_median_of_each_repeat_s_ratio() -> None:
    def flight(frame_ms: float) -> dict[str, Any]:
        cpu = dict.fromkeys(ROLES, 1.0)
        return {"frames": 10, "lost": 0, "cpu_ms_per_frame": cpu, "links": {},
                "median_timings_ms": {"total": frame_ms}}  # fmt: skip

    # repeat by repeat: 0.5, 2.0 and 1.1; the medians' ratio (40 / 30) would hide the pairing
    runs = {ALONE: [flight(40.0), flight(20.0), flight(30.0)],
            "master-worker 1": [flight(20.0), flight(40.0), flight(33.0)]}  # fmt: skip
    table = summary_table([10.0, 10.0, 10.0], 27, runs)
    alone, path = table[1], table[2]
    assert alone["path"] == ALONE and "vs_alone" not in alone
    assert path["vs_alone"] == pytest.approx(1.1)
    # under another heap policy a path is paired with the master alone under that policy
    glibc = {heap_label(label, HeapPolicy.GLIBC):
             [{**flight(2 * f["median_timings_ms"]["total"]), "heap": "glibc"} for f in got]
             for label, got in runs.items()}  # fmt: skip
    rows = {row["path"]: row for row in summary_table([10.0, 10.0, 10.0], 27, {**runs, **glibc})}
    assert rows["master-worker 1 (glibc heap)"]["vs_alone"] == pytest.approx(1.1)
    assert "vs_alone" not in rows[f"{ALONE} (glibc heap)"]
    # a repeat without a frame time leaves the pairing out rather than pairing the wrong repeats
    del runs[ALONE][1]["median_timings_ms"]["total"]
    assert "vs_alone" not in summary_table([10.0, 10.0, 10.0], 27, runs)[2]


def test_the_master_alone_computes_whatever_the_option_and_has_no_member_hosts() -> None:
    label, topology, workers = PATHS[0]
    assert label == ALONE
    spec = path_spec(label, topology, workers, master_computes=False, pin=True)
    assert spec.master_computes and spec.hosts == () and spec.master_cpus == host_cpus()[0]
    assert not path_spec(*PATHS[1]).master_computes  # the members' paths keep the option


def test_pinned_hosts_take_one_cpu_each_the_ground_the_first() -> None:
    spec = path_spec("master-foreman-worker 2x2", Topology.MASTER_FOREMAN_WORKER, (2, 2), True, pin=True)
    ground, members = host_cpus()
    assert spec.master_cpus == spec.aux_cpus == ground == str(min(os.sched_getaffinity(0)))
    assert [h.cpus for h in spec.hosts] == [members[0], members[1 % len(members)]]
    assert spec.master_computes
    assert path_spec("p", Topology.MASTER_WORKER, (1,)).hosts[0].cpus is None  # not pinned by default


def test_the_workload_is_the_same_in_process_and_on_the_master() -> None:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    default_size, default, default_args = workload_of(parser.parse_args([]))
    # no level given: both resolve it for the frames' size (752x480: level 1), the master by itself
    assert default_size == (752, 480) and default == YawSettings(pyramid_level=1)
    assert default_args == ("--grid", "8x5", "--patch-size", "32", "--job-encoding", "mono8",
                            "--job-quality", "90")  # fmt: skip
    args = parser.parse_args(["--resolution", "1920x1080", "--grid", "16x12", "--patch-size", "128",
                              "--pyramid-level", "0", "--job-encoding", "jpeg",
                              "--job-quality", "75"])  # fmt: skip
    size, settings, master_args = workload_of(args)
    assert size == (1920, 1080)
    assert (settings.grid_cols, settings.grid_rows, settings.patch_size_px, settings.pyramid_level) == (
        16,
        12,
        128,
        0,
    )
    assert master_args == ("--grid", "16x12", "--patch-size", "128", "--pyramid-level", "0",
                           "--job-encoding", "jpeg", "--job-quality", "75")  # fmt: skip
    with pytest.raises(CapatazError, match="--grid"):
        workload_of(parser.parse_args(["--grid", "16by12"]))


def test_the_turns_flight_starts_near_its_first_turn_and_too_many_frames_is_one_error(tmp_path: Path) -> None:
    """``--flight turns``: the hover's first 120 frames barely turn, so the master's refinement (frames
    turning more than refine_min_deg, which it computes alone) was never measured by this bench."""
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--flight", "turns", "--frames", "10", "--resolution", "160x120"])
    args.out = tmp_path
    frames = flight_frames(args)
    flight = simulated_flight(CameraSettings(frames=10, width=160, height=120, flight=FlightName.TURNS))
    assert len(frames) == 10 and np.array_equal(frames[3], flight.frame(TURNS_FROM_FRAME + 3))
    assert sorted(p.name for p in args.frame_dir.iterdir())[:1] == ["00000.pgm"]
    turned = np.degrees(np.abs(np.diff(flight.yaw_rad[TURNS_FROM_FRAME : TURNS_FROM_FRAME + 60])))
    assert np.mean(turned > YawSettings().refine_min_deg) > 0.5
    too_long = parser.parse_args(["--flight", "turns", "--frames", str(flight.n_frames)])
    too_long.out = tmp_path
    with pytest.raises(CapatazError, match="--flight turns has"):
        flight_frames(too_long)


def test_roles_sum_their_processes_net_of_idle_per_frame() -> None:
    before = {
        "master/master/0": 1.0,
        "worker/h1/0": 2.0,
        "worker/h1/1": 2.0,
        "router": 0.5,
        "camera/c/0": 3.0,
    }
    after = {"master/master/0": 1.5, "worker/h1/0": 3.0, "worker/h1/1": 2.6, "router": 0.7, "camera/c/0": 9.0}
    idle = {"master/master/0": 0.01, "router": 0.02}
    cpu = cpu_ms_per_frame(before, after, idle, flight_s=10.0, frames=100)
    assert cpu == pytest.approx({"master": 4.0, "foreman": 0.0, "worker": 16.0, "router": 0.0})


@given(st.dictionaries(st.sampled_from(["master/m/0", "worker/a/0", "foreman/a/0", "router"]), seconds),
       seconds, seconds, st.integers(1, 1000))  # fmt: skip
def test_figures_are_never_negative_and_idle_only_lowers_them(
    before: dict[str, float], spent: float, idle: float, frames: int
) -> None:
    after = {name: value + spent for name, value in before.items()}
    raw = cpu_ms_per_frame(before, after, {}, 1.0, frames)
    net = cpu_ms_per_frame(before, after, dict.fromkeys(before, idle), 1.0, frames)
    assert set(raw) == set(ROLES) == set(net)
    assert all(0.0 <= net[r] <= raw[r] + 1e-9 for r in ROLES)


@pytest.mark.zenoh
@pytest.mark.slow
def test_every_path_computes_every_frame_with_cpu_on_the_members(tmp_path: Path) -> None:
    # a member that misses its deadline is paused (1 s, doubling) and the master computes its share: on the
    # CI host, loaded by the other xdist worker, 0.3 s (the default) was missed twice over 30 frames and the
    # master computed 60 % of the patches. Members get 1 s (the frame's budget): this measures the balanced
    # path, not the fault path (tests/services/test_scatter.py, tests/integration/test_cluster_faults.py)
    args = _bench_args(
        tmp_path, "--frames", "30", "--fps", "10", "--idle-s", "0.5", "--repeats", "1", *GENEROUS_DEADLINE
    )
    result = run(args)
    paths = result["json"]["paths"]
    assert [p["path"] for p in paths] == [
        ALONE,
        "master-worker 1",
        "master-foreman-worker 1x1",
        "master-foreman-worker 2x2",
    ]
    assert result["json"]["in_process_cpu_ms_per_frame"] > 0 and result["json"]["heap_policies"] == ["warm"]
    alone, paths = paths[0], paths[1:]
    # the master alone measured every patch of every pair itself (the yaw core's grid, 29 pairs)
    patches = YawSettings().grid_cols * YawSettings().grid_rows
    assert alone["lost"] == 0 and alone["patches_by_member"] == {SELF: 29 * patches}
    assert all(alone["gross_cpu_ms_per_frame"][role] == 0 for role in ("foreman", "worker"))
    for path in paths:
        assert path["lost"] == 0 and path["frames"] == 30
        # CPU is read from /proc in 10 ms ticks; less each process's idle rate, a role's frames can read 0
        # on a loaded host (the master's and a worker's each did once in the suite); before it, they cannot
        assert path["median_timings_ms"]["total"] > 0.0  # the master's frame in to yaw out
        gross, net = path["gross_cpu_ms_per_frame"], path["cpu_ms_per_frame"]
        assert gross["master"] > 0 and gross["worker"] > 0
        assert all(0 <= net[role] <= gross[role] for role in net)
        # the master dispatches: its members compute most patches. It takes a share of a frame whose member
        # is late (its documented fallback): on a host loaded by four processes on two cores, 100 of 360
        # patches (with more than 4x asserted, that failed once); a master that computed alone gives 0 here
        members = path["patches_by_member"]
        assert members_outweigh_master(members), members
    assert len(result["table"]) == 5 and all("vs_alone" in row for row in result["table"][2:])


@pytest.mark.zenoh
@pytest.mark.slow
def test_across_emulated_hosts_the_frames_cross_the_ground_link(tmp_path: Path) -> None:
    if (reason := unavailable_reason()) is not None:
        pytest.skip(reason)
    # 30 frames, not 10, and 1 s deadlines (see the test above): with 0.3 s the foreman missed two on the
    # loaded CI host, 720 of 1,160 patches moved to the master
    args = _bench_args(
        tmp_path, "--frames", "30", "--fps", "10", "--idle-s", "0.5", "--netns", "--link-mbit", "100",
        *GENEROUS_DEADLINE,
    )  # fmt: skip
    label, topology, workers = PATHS[2]  # master-foreman-worker 1x1
    path = cluster_path(label, topology, workers, args)
    # less each process's idle rate a role's CPU over 10 frames can read 0 on a loaded host (CI did for the
    # worker): gross CPU is read; the patches were computed on h1 (the master's fallback share aside)
    assert path["lost"] == 0 and path["gross_cpu_ms_per_frame"]["worker"] > 0
    members = path["patches_by_member"]
    assert members_outweigh_master(members) and all("/h1/" in k for k in members if k != SELF), members
    # the master's level image (752x480 at level 1 is 90 kB; the jobs carry at least their crops) goes out
    # on the ground link and comes in on h1's, every frame; the replies are smaller
    ground, h1 = path["links"]["ground"], path["links"]["h1"]
    assert ground["tx_bytes_per_frame"] > 10_000 and h1["rx_bytes_per_frame"] > 10_000
    assert h1["tx_bytes_per_frame"] < h1["rx_bytes_per_frame"]
