"""The cluster file's master options reach the master's command line, and parse there."""

from __future__ import annotations

import argparse

from services.master.settings import add_master_arguments, master_settings_from_args
from services.tools.cluster_file import ClusterSpec, HostSpec, master_command


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
