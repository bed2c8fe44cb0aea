"""The cluster file's master and foreman options reach their command lines, and parse there."""

from __future__ import annotations

import argparse

import pytest
from pydantic import ValidationError

from common.dispatch import DispatchSettings
from services.master.settings import add_master_arguments, master_settings_from_args
from services.runtime.cli import dispatch_from_args
from services.tools.cli import build_parser
from services.tools.cluster_file import (
    ClusterSpec,
    HostSpec,
    add_deadline_argument,
    foreman_command,
    master_command,
    with_deadline,
)


def test_a_cluster_files_job_encoding_reaches_the_masters_command_line() -> None:
    hosts = (HostSpec(name="h1", workers=1),)
    zstd = master_command(ClusterSpec(name="thin", hosts=hosts, job_encoding="zstd")).args
    assert zstd[-2:] == ("--job-encoding", "zstd")
    parser = argparse.ArgumentParser()
    add_master_arguments(parser)
    known, _ = parser.parse_known_args(list(zstd[1:]))
    assert master_settings_from_args(known).job_encoding == "zstd"
    default = master_command(ClusterSpec(name="plain", hosts=hosts)).args  # the default is left unsaid
    assert "--job-encoding" not in default
    assert master_settings_from_args(parser.parse_known_args(list(default[1:]))[0]).job_encoding == "mono8"
    jpeg = master_command(ClusterSpec(name="radio", hosts=hosts, job_encoding="jpeg", job_quality=75)).args
    assert jpeg[-4:] == ("--job-encoding", "jpeg", "--job-quality", "75")
    settings = master_settings_from_args(parser.parse_known_args(list(jpeg[1:]))[0])
    assert (settings.job_encoding, settings.job_quality) == ("jpeg", 75)
    assert "--job-quality" not in default
    with pytest.raises(ValidationError):
        ClusterSpec(name="radio", hosts=hosts, job_quality=0)


def test_a_clusters_min_deadline_reaches_the_master_and_the_foremen() -> None:
    hosts = (HostSpec(name="h1", workers=1),)
    spec = with_deadline(ClusterSpec(name="slow-host", hosts=hosts), 900.0)
    parser = argparse.ArgumentParser()
    add_master_arguments(parser)
    known, _ = parser.parse_known_args(list(master_command(spec).args[1:]))
    assert master_settings_from_args(known).dispatch.min_deadline_s == 0.9
    foreman = build_parser().parse_args([*foreman_command(spec, hosts[0]).args])
    assert dispatch_from_args(foreman).min_deadline_s == 0.9
    # the default is left unsaid, and is the dispatcher's
    plain = ClusterSpec(name="plain", hosts=hosts)
    assert with_deadline(plain, None) is plain and "--min-deadline-ms" not in master_command(plain).args
    default = DispatchSettings().min_deadline_s
    assert (
        master_settings_from_args(
            parser.parse_known_args(list(master_command(plain).args[1:]))[0]
        ).dispatch.min_deadline_s
        == default
    )


def test_a_min_deadline_out_of_its_bounds_is_refused() -> None:
    with pytest.raises(ValidationError):
        ClusterSpec(name="bad", hosts=(HostSpec(name="h1", workers=1),), min_deadline_ms=0.0)
    parser = argparse.ArgumentParser()
    add_deadline_argument(parser)
    with pytest.raises(SystemExit):
        parser.parse_args(["--min-deadline-ms", "nan"])
    assert parser.parse_args(["--min-deadline-ms", "1000"]).min_deadline_ms == 1000.0


def test_a_load_tests_masters_take_the_files_options_regression() -> None:
    # the load test built its masters' command lines itself and left out the file's job_encoding
    spec = ClusterSpec(name="thin", hosts=(HostSpec(name="h1", workers=1),), job_encoding="zstd", uav="uav0")
    standby = master_command(spec, "s1", "uav1")
    assert standby.name == "master/s1/0"
    args = list(standby.args)
    assert args[args.index("--node") + 1] == "s1" and args[args.index("--uav") + 1] == "uav1"
    assert args[args.index("--job-encoding") + 1] == "zstd"
    assert master_command(spec).name == "master/master/0" and "uav0" in master_command(spec).args
