"""Read capataz's yaw estimates from a Zenoh client (the README's quick-start).

python docs/examples/read_yaw.py tcp/127.0.0.1:7447 --count 20
python docs/examples/read_yaw.py tls/127.0.0.1:7447 --tls out/secure/certs   # the read-only client cert
"""

from __future__ import annotations

import argparse
import json
import sys
import threading

import zenoh

from common.wire.codec import decode
from common.wire.messages import YawEstimate

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("endpoint", help="the router, e.g. tcp/127.0.0.1:7447 or tls/127.0.0.1:7447")
parser.add_argument("--uav", default="uav0")
parser.add_argument("--count", type=int, default=100, help="stop after this many estimates")
parser.add_argument("--timeout", type=float, default=120.0, help="give up after this many seconds")
parser.add_argument("--tls", metavar="DIR", help="folder with ca.pem, client.pem, client.key (mutual TLS)")
args = parser.parse_args()

config = zenoh.Config()
config.insert_json5("mode", '"client"')
config.insert_json5("connect/endpoints", json.dumps([args.endpoint]))
config.insert_json5("scouting/multicast/enabled", "false")
config.insert_json5("connect/timeout_ms", str(int(args.timeout * 1000)))  # wait for a router still starting
if args.tls:
    tls = {
        "root_ca_certificate": f"{args.tls}/ca.pem",
        "connect_certificate": f"{args.tls}/client.pem",
        "connect_private_key": f"{args.tls}/client.key",
        "enable_mtls": True,
        "verify_name_on_connect": False,
    }
    config.insert_json5("transport/link/tls", json.dumps(tls))

received = 0
done = threading.Event()


def on_yaw(sample: zenoh.Sample) -> None:  # the callback only decodes, prints and counts
    global received
    attachment = sample.attachment.to_bytes() if sample.attachment is not None else b""
    yaw = decode(sample.payload.to_bytes(), attachment, YawEstimate)
    sigma_rad = yaw.yaw_variance_rad2**0.5
    # one write a line: a terminal or pipe shared with other processes never gets a line cut in two
    sys.stdout.write(
        f"frame {yaw.seq}: yaw {yaw.yaw_rad:+.4f} rad, sigma {sigma_rad:.4f} rad ({yaw.provenance.value})\n"
    )
    sys.stdout.flush()
    received += 1
    if received >= args.count:
        done.set()


with zenoh.open(config) as session:
    subscriber = session.declare_subscriber(f"capataz/uav/{args.uav}/yaw", on_yaw)
    finished = done.wait(args.timeout)
    subscriber.undeclare()
raise SystemExit(0 if finished else f"only {received} of {args.count} estimates in {args.timeout:.0f} s")
