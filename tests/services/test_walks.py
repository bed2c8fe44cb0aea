"""The walks of issue 24, measured with :func:`tests.walks.walk` (``sys.setprofile``: the project modules
control enters, consecutive calls within one module counting as one entry):

- one IMU sample from the estimator service's callback to its published attitude;
- one frame from the master's callback to its published yaw (the master computing alone: the yaw core's
  distributable stage on its own thread, as a member would).

Every project module is entered at most twice on both walks.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from common.estimation.coupling_types import EkfKind
from common.estimation.measurements import ImuMeasurement, RangeMeasurement
from common.sim.flight import hover_flight, turns_flight
from common.sim.stream import flight_measurements
from common.wire import keys
from common.wire.codec import encode
from common.wire.measurements import message_of
from common.wire.messages import Frame
from services.estimator import EstimatorService, EstimatorSettings
from services.master import MasterService, MasterSettings
from services.runtime.transport import TransportSettings, open_session
from tests.services.fakes import FakeBytes, FakePublisher
from tests.walks import entries_per_module, walk


def _sample(message: Any, key: str) -> SimpleNamespace:
    payload, attachment = encode(message)
    return SimpleNamespace(payload=FakeBytes(payload), attachment=FakeBytes(attachment), key_expr=key)


@pytest.mark.parametrize("kind", [EkfKind.BIAS, EkfKind.PAPER_C])
def test_an_imu_sample_enters_no_module_more_than_twice_from_the_callback_to_the_attitude(
    kind: EkfKind,
) -> None:
    flight = turns_flight(seed=0)
    stream = list(flight_measurements(flight, 0, 6))
    # no reordering lag: the sample the callback gets is the one applied and published in the same turn
    settings = EstimatorSettings(initial_yaw_rad=float(flight.yaw_rad[0]), max_lag_s=0.0, filter=kind)
    service = EstimatorService("walk", 0, TransportSettings(), settings)
    service._attitude_pub, service._pose_pub = FakePublisher(), FakePublisher()  # type: ignore[assignment]
    last = max(i for i, m in enumerate(stream) if isinstance(m, ImuMeasurement))
    callbacks = {ImuMeasurement: service._on_imu, RangeMeasurement: service._on_range}
    for seq, m in enumerate(stream[:last]):  # the filter, the VO and the queues warmed up
        key, message = message_of("uav0", seq, m)
        callbacks.get(type(m), service._on_frame)(_sample(message, key))  # type: ignore[arg-type]
        while service.step(0.0):
            pass
    key, message = message_of("uav0", last, stream[last])
    sample = _sample(message, key)
    published = len(service._attitude_pub.puts)  # type: ignore[attr-defined]

    def receive_and_step() -> bool:
        service._on_imu(sample)  # type: ignore[arg-type]
        return service.step(0.0)

    entries = walk(receive_and_step)

    assert len(service._attitude_pub.puts) == published + 1  # type: ignore[attr-defined]
    counts = entries_per_module(entries)
    assert max(counts.values()) <= 2, (counts, entries)
    # one IMU step is one call into the filter's module and its math module, with the read-outs
    filter_module, math_module = {
        EkfKind.BIAS: ("common/estimation/eskf.py", "common/estimation/eskf_kernels.py"),
        EkfKind.PAPER_C: ("common/estimation/ekf.py", "common/estimation/ekf_models.py"),
    }[kind]
    assert counts[filter_module] == 1 and counts[math_module] == 1, entries
    # the filters are called directly (no dispatch on method names in common/estimation/filters.py)
    assert "common/estimation/filters.py" not in counts
    # UAV, sender and time checked once (the input gate), values once (the checked measurement), each where it
    # arrives
    assert counts["services/runtime/gate.py"] == 1 and counts["services/estimator/inputs.py"] == 1
    assert counts["common/estimation/coupling.py"] <= 2 and counts["services/estimator/service.py"] <= 2


@pytest.mark.zenoh
def test_a_frame_enters_no_yaw_module_more_than_twice_from_the_callback_to_the_published_yaw() -> None:
    flight = hover_flight(seed=0, n_frames=3)
    samples = [
        _sample(
            Frame(uav="uav0", seq=k, stamp_s=k / 20, width=752, height=480, pixels=flight.frame(k)),
            keys.camera_key("uav0"),
        )
        for k in range(3)
    ]
    transport = TransportSettings()  # loopback, no scouting: this session meets nobody
    with open_session(transport) as session:
        master = MasterService("walk", 0, transport, MasterSettings(election=False))
        master.session = session
        master._publisher = session.declare_publisher(keys.yaw_key("uav0"))
        for sample in samples[:2]:  # the stream started and one pair measured: spectra cached
            master._on_frame(sample)  # type: ignore[arg-type]
            assert master.serve_once(0.0)

        def receive_and_serve() -> bool:
            master._on_frame(samples[2])  # type: ignore[arg-type]
            return master.serve_once(0.0)

        entries = walk(receive_and_serve)

        assert master.counters.get("yaw_out") == 3
    counts = entries_per_module(entries)
    yaw_core = {m: n for m, n in counts.items() if m.startswith("common/yaw/") or m == "common/images.py"}
    assert {"common/yaw/tracker.py", "common/yaw/correlation.py", "common/yaw/fit.py"} <= set(yaw_core)
    assert max(yaw_core.values()) <= 2, (yaw_core, entries)
    assert (
        counts["common/images.py"] == 1
    )  # the frame checked once in the yaw core (the wire checks its message)
    assert max(counts.values()) <= 2, (counts, entries)
    # the plan consults the trust monitor once, the guard admits a turn's frames in one call; the intake is
    # entered by zenoh's callback and the turn, the service by the turn and the frame's processing, the
    # hand-off by the callback's put and the turn's drain, the counters by the round and the frame's end
    for module in ("common/dispatch/dispatcher.py", "common/dispatch/trust.py", "services/runtime/guard.py"):
        assert counts[module] == 2, (module, entries)
    assert counts["services/master/service.py"] == 2 and counts["services/master/frames.py"] == 2, entries
    assert counts["services/runtime/handoff.py"] == 2 and counts["services/runtime/counters.py"] <= 2, entries
