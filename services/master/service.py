"""The master of one UAV stream: admitted frame -> shares -> merged measurement -> yaw.

Zenoh's callback only hands each frame sample off, with its arrival times, to a bounded inbox (as
zenoh-python's examples do); the master's frames thread runs the rest. Every frame passes the stream gate
(:mod:`common.streams`: foreign UAV, size, encoding, a second sender within an epoch, seq and stamp jumps
refused and counted; a confirmed restart is a new epoch whose yaw continues the last one) and waits in a
short FIFO. Its lens and mount are the stream's rig (:mod:`services.runtime.rig_follow`; a frame naming a
rig not received is refused) unless the master was given camera or mount options. Several masters may
serve one UAV: one is active (:mod:`services.master.election`), the others take over from the last yaw.

Topology is a setting: ``master-worker`` (members = every worker) or ``master-foreman-worker``
(members = foremen, each splitting its block among its workers). Balancing and self-compute are the
:class:`~common.dispatch.Dispatcher`'s settings. With no members at all the master computes alone.
The central stage is the yaw core's own ``YawTracker.conclude``, fed the merged measurement, so the
published yaw equals the in-process tracker's when no frame is dropped.
"""

from __future__ import annotations

import logging
import threading
import time
from functools import partial
from typing import Any

import zenoh

from common.dispatch import SELF, Dispatcher
from common.errors import CapatazError
from common.members import Role, Topology
from common.rig import Rig
from common.wire import keys
from common.wire.messages import (
    BlockJob,
    BlockResult,
    Frame,
    PatchJob,
    PatchResult,
    YawEstimate,
    YawJobSettings,
)
from common.yaw import YawTracker, for_frame, make_patch_grid
from common.yaw.measurement import merge_measurements
from services.master.election import Election, LeaderSessions
from services.master.frames import FrameIntake
from services.master.gyro import GyroPrior
from services.master.lens import CameraSource, stream_geometry
from services.master.own_share import OwnShare
from services.master.published import (
    ANONYMOUS,
    PublishedLedger,
    PublishedYaw,
    PublishVerdict,
    YawAnchor,
    initial_estimate,
    measured_estimate,
    session_of,
    take_over_anchor,
)
from services.master.refine import MemberRefine
from services.master.settings import MasterSettings
from services.master.stream import YawStream
from services.runtime.allocator import HeapTrim
from services.runtime.cli import IDLE_PROCESS_MB, LARGEST_SHARE_MB
from services.runtime.guard import DispatchGuard
from services.runtime.membership import LiveMembers
from services.runtime.rig_follow import follow_stream_rig
from services.runtime.round import FrameWork, job_band
from services.runtime.scatter import Scatter
from services.runtime.service import ConfiguredService
from services.runtime.transport import source_of

logger = logging.getLogger(__name__)

#: a standby looks at the election at least this often (s)
STANDBY_POLL_S = 0.02


class MasterService(ConfiguredService[MasterSettings]):
    role = Role.MASTER

    def setup(self) -> None:
        settings = self.settings
        # a frame's arrays reuse the pages the last one freed; past an idle process and one largest share
        # (its own share is at most a whole frame) they go back after a frame (services.runtime.allocator)
        self.heap = HeapTrim.for_service(IDLE_PROCESS_MB + LARGEST_SHARE_MB)
        self.yaw_settings = settings.yaw
        #: the guard first: the intake's source lock is part of it
        self.guard = DispatchGuard(self.name, self.counters, settings.trust)
        self.intake = FrameIntake(self, self.guard, settings)
        self.slot = self.intake.slot
        #: zenoh's frame callback is the intake's: it only hands the sample off (the frames thread gates it)
        self._on_frame = self.intake.receive
        #: protects the published yaw (zenoh's yaw callback records, the frames thread reads)
        self._recent_lock = threading.Lock()
        #: yaw published for this UAV by seq, from sessions that led it (a take-over starts there)
        self.published = PublishedLedger(ANONYMOUS, 4 * settings.recent_frames)
        self.leader_sessions = LeaderSessions(self.name, self.count_error)
        self._leaders_resolved = False
        self.election: Election | None = None
        self._job_types: tuple[type[PatchJob], type[PatchResult]] = (BlockJob, BlockResult)
        self.stream: YawStream | None = None
        self.scatter: Scatter | None = None
        self.live = LiveMembers(self.member_role)
        self._entities: list[Any] = []
        self._publisher: Any = None
        self._last_shares: dict[str, float] = {}
        #: the turn's and its frame's counts, added to the counters once when it is done (:meth:`_process`)
        self._frame_counts: dict[str, int] = {}
        prior = settings.prior
        self.gyro = GyroPrior.of(prior, self.counters, self.intake.gate, self.name)
        self.lens = CameraSource(settings.prior.lens)  # a calibration file is read here, once
        #: the stream's rig (capataz/uav/{uav}/rig); camera or mount options given to the master override it
        self.intake.rigs = follow_stream_rig(settings.uav, self, prior.lens, prior.rig_mount)

    # -- wiring -----------------------------------------------------------------------------------------
    def start(self, session: zenoh.Session) -> None:
        self.published.own_session = str(session.info.zid())
        self._publisher = session.declare_publisher(keys.yaw_key(self.settings.uav))
        self._entities.append(self._publisher)
        self._entities.append(session.declare_subscriber(keys.yaw_key(self.settings.uav), self._on_yaw))
        if self.intake.rigs is not None:
            self._entities.append(self.intake.rigs.start(session))
        if self.settings.election:
            self.election = Election(session, self.settings.uav, self.node, self.index)
        self._entities.append(
            session.liveliness().declare_subscriber(keys.ALIVE_ALL, self._on_alive, history=True)
        )
        self._entities.append(session.declare_subscriber(keys.camera_key(self.settings.uav), self._on_frame))
        if self.gyro.enabled:
            self._entities.append(session.declare_subscriber(keys.imu_key(self.settings.uav), self._on_imu))
        self.spawn(self._serve, "frames")

    @property
    def member_role(self) -> Role:
        return Role.WORKER if self.settings.topology is Topology.MASTER_WORKER else Role.FOREMAN

    def _on_alive(self, sample: zenoh.Sample) -> None:
        event = self.member_event(sample)
        if event is not None:
            member, joined = event
            self.guard.note_alive(member.name, joined)
            self.live.on_event(member, joined, self.counters, self.scatter)

    def stop(self) -> None:
        # the publisher stays declared (the frames thread may still be publishing; the session closes it)
        if self.election is not None:
            self.election.close()

    def _on_imu(self, sample: zenoh.Sample) -> None:
        self.gyro.on_sample(self.decode_sample(sample, self.gyro.message_type), source_of(sample))

    def _on_yaw(self, sample: zenoh.Sample) -> None:
        estimate = self.decode_sample(sample, YawEstimate)
        if estimate is None:
            return
        if estimate.uav != self.settings.uav:
            self.count_error("refused_yaw_foreign_uav", "yaw of another UAV refused", f"{estimate.uav!r}")
            return
        yaw = PublishedYaw.of(estimate, session_of(source_of(sample)))
        with self._recent_lock:
            verdict = self.published.record(yaw, self._leaders_resolved)
        if verdict is PublishVerdict.REFUSED:
            self.count_error("yaw_untrusted", "refused yaw of a session that never led", yaw.session)

    def _trust_leaders(self) -> None:
        """Trust the yaw of the sessions answering as the other alive leaders (none while this one leads)."""
        assert self.election is not None and self.session is not None
        for session in self.leader_sessions.update(self.session, self.election.leaders()):
            with self._recent_lock:
                self.published.trust(session)
        self._leaders_resolved = self.leader_sessions.resolved

    def _apply_membership(self, dispatcher: Dispatcher) -> None:
        # nothing to do unless a liveliness token came or went (members whose liveliness churns are paused
        # by the guard's admission, each turn)
        self.live.update(dispatcher)

    def shares(self) -> dict[str, float]:
        return dict(self._last_shares)

    def queue_depths(self) -> dict[str, int]:
        return {"frames": self.slot.depth(), "inbox": self.intake.inbox.depth()}

    def healthy(self) -> tuple[bool, str]:
        gate = self.intake.gate
        if recent := gate.recent_refusals():
            return False, f"degraded: {recent} inputs refused in the last {gate.window_s:.0f} s"
        role = "active" if self.election is None or self.election.leading else "standby"
        return True, role

    # -- frames -----------------------------------------------------------------------------------------
    def _serve(self) -> None:
        assert self.session is not None
        worker = self.settings.topology is Topology.MASTER_WORKER
        self._job_types = (PatchJob, PatchResult) if worker else (BlockJob, BlockResult)
        while not self.stop_event.is_set():
            self.serve_once(0.05)

    def serve_once(self, timeout_s: float) -> bool:
        """One turn of the frames thread: the election, the frames received so far through the gate, then the
        oldest queued frame measured and published (waits up to ``timeout_s`` for a frame when none is
        queued); True when a frame was measured."""
        if self.election is not None:
            self._trust_leaders()
            if self.election.update():
                self._take_over()
        standby = self.election is not None and not self.election.leading
        # standing by, frames go to the recent ones only
        wait_s = min(timeout_s, STANDBY_POLL_S) if standby else timeout_s
        item = self.intake.next_frame(not standby, wait_s, self._frame_counts)
        if item is None:
            if self._frame_counts:  # the turn's counts (else added with its frame's, at its end)
                self.counters.update(self._frame_counts)
                self._frame_counts = {}
            return False
        self._process(*item)
        return True

    def _process(self, epoch: int, frame: Frame) -> None:
        t0 = time.perf_counter()
        try:
            estimate = self._estimate(epoch, frame, t0)
        except (CapatazError, ValueError) as exc:  # a raw ValueError is a bug: counted apart, traceback
            self.count_failure("frame_errors", f"frame {frame.seq} failed", exc)
            estimate = None
        counts, self._frame_counts = self._frame_counts, {}
        timings: dict[str, float] = {}
        # the declared source: standbys keep only yaw of sessions that led (services.master.published)
        if estimate is not None and self.publish(
            self._publisher, estimate, source_info=zenoh.SourceInfo(self._publisher.id, estimate.seq)
        ):  # (not published: shutting down, the session is closing under us)
            if self.trajectory_tap is not None:
                self.trajectory_tap.write(estimate)
            counts["yaw_out"] = 1
            timings["frame"] = estimate.timings_ms["total"]
        if self.heap.after_job():
            counts["heap_trims"] = 1
        if counts or timings:
            self.counters.update(counts, timings)  # the frame's counts, once

    def _take_over(self) -> None:
        """Continue from the last published yaw: anchor on the newest kept frame whose yaw was published,
        then measure the kept frames after it (frames a failed master took but did not publish)."""
        self.counters.inc("takeovers")
        with self.intake.recent_lock:
            recent = list(self.intake.recent)
        with self._recent_lock:
            found = take_over_anchor(recent, self.published.trusted_yaws())
        if found is None:  # the next frame starts a stream that continues the newest published yaw
            return
        epoch, frame, anchor = found
        self._start_stream(frame, epoch, anchor)
        for later_epoch, later in recent:
            if later_epoch == epoch and later.seq > frame.seq:
                self._process(later_epoch, later)

    def _last_yaw(self) -> YawAnchor:
        """This master's stream's yaw, else the newest trusted published one, else 0 (the first frame's)."""
        if self.stream is not None:
            return YawAnchor(float(self.stream.state.yaw_rad), float(self.stream.state.yaw_variance_rad2))
        with self._recent_lock:
            newest = self.published.newest_trusted()
        return YawAnchor() if newest is None else newest.anchor

    def _start_stream(self, frame: Frame, epoch: int, anchor: YawAnchor, rig: Rig | None = None) -> YawStream:
        """A stream from ``frame`` on, continuing ``anchor``: the lens and mount of the stream's ``rig`` when
        it has one (and the master was given neither), else the master's options; the gyro prior follows."""
        assert self.session is not None
        yaw_settings = for_frame(self.yaw_settings, (frame.height, frame.width))
        grid = make_patch_grid((frame.height, frame.width), yaw_settings)
        prior = self.settings.prior
        if rig is None and frame.rig_id is not None and self.intake.rigs is None:
            logger.warning(
                "%s: the stream's rig %s is overridden by the master's options", self.name, frame.rig_id
            )
        geometry = stream_geometry(prior, self.lens, frame.width, frame.height, rig, self.name)
        camera, R_body_camera, axis, offset, R_body_imu = geometry
        self.gyro.for_stream(axis, offset, R_body_imu, camera is not None, self.name)
        tracker = YawTracker(prior.tracker_settings(yaw_settings, camera), grid, R_body_camera)
        state = tracker.initial_state(frame.pixels, with_spectra=False, stamp_s=frame.stamp_s,
            yaw_rad=anchor.yaw_rad, yaw_variance_rad2=anchor.yaw_variance_rad2,
            R_level_body=self.gyro.tilt(frame.stamp_s, self._frame_counts))  # fmt: skip
        dispatcher = Dispatcher(self.settings.dispatch, grid.n_patches)
        dispatcher.trust = self.guard.monitor()
        level = grid.level_image(frame.pixels)
        stream = YawStream(
            yaw_settings, YawJobSettings.of(yaw_settings), grid, tracker, state, frame.seq, level, dispatcher,
            epoch, all_indices=grid.all_indices, rig_id=None if rig is None else rig.rig_id,
        )  # fmt: skip
        job_type, result_type = self._job_types
        self.scatter = Scatter(
            self.session, dispatcher, keys.work_key_of, job_type, result_type, self.counters
        )
        self.stream = stream
        return stream

    def _estimate(self, epoch: int, frame: Frame, t0: float) -> YawEstimate | None:
        """The yaw of one admitted frame (None: already measured, e.g. replayed at a take-over)."""
        assert self.session is not None
        stream = self.stream
        rig = self.intake.frame_rigs.get(frame.seq)  # the stream's rig of the frame (None: own options)
        rig_id = None if rig is None else rig.rig_id
        if stream is None or epoch != stream.epoch or rig_id != stream.rig_id:
            # a new epoch (first frame, camera restart, take-over without anchor) or a new rig: the yaw
            # continues
            anchor = self._last_yaw()
            stream = self._start_stream(frame, epoch, anchor, rig)
            dropped = self.slot.dropped + self.intake.inbox.dropped
            return initial_estimate(self.settings.uav, frame.seq, frame.stamp_s, anchor, t0, dropped)
        if frame.seq <= stream.prev_seq:
            self.counters.inc("frames_already_measured")
            return None
        assert self.scatter is not None
        self._apply_membership(stream.dispatcher)
        grid, settings = stream.grid, stream.settings
        level = grid.level_image(frame.pixels)
        prev_level, prev_seq = stream.prev_level, stream.prev_seq
        t_level = time.perf_counter()

        own_share = OwnShare(
            grid, level, prev_level, stream.cache, settings, self.settings.uav, frame.seq, prev_seq
        )

        encoding, quality = self.settings.job_encoding, self.settings.job_quality
        work = FrameWork(
            stream=self.settings.uav,
            seq=frame.seq,
            prev_seq=prev_seq,
            settings=stream.wire_settings,
            budget_s=self.settings.budget_s,
            crops=partial(grid.crop_level, level),
            prev_crops=partial(grid.crop_level, prev_level),
            compute_self=own_share,
            band=partial(job_band, grid, level, encoding, quality=quality),
        )
        plan = stream.dispatcher.plan(frame.seq, prev_seq, time.monotonic())
        try:
            report = self.scatter.run(work, plan)
            measurement = merge_measurements(report.parts, stream.all_indices)
        except (CapatazError, ValueError) as exc:  # never lose a frame: compute it here (a bug counted apart)
            self.count_failure("local_fallback", f"frame {frame.seq}: round failed, computing locally", exc)
            stream.dispatcher.forget_history(SELF)
            measurement = own_share(stream.all_indices, stream.all_indices)
            report = None
        t_round = time.perf_counter()
        if report is not None:
            self.guard.vet(
                stream.dispatcher.trust, report.owners, report.parts, measurement, grid.centres_px, settings
            )
        # a stamp that does not increase (a bad stamp file) leaves this pair untimed: no rate limit, no gyro
        previous_s = stream.state.stamp_s
        stamp: float | None = frame.stamp_s if previous_s is None or frame.stamp_s > previous_s else None
        counts = self._frame_counts
        if stamp is None:
            counts["stamps_not_increasing"] = counts.get("stamps_not_increasing", 0) + 1
        gyro = self.gyro.delta_rad(previous_s, stamp, counts) if stamp is not None else None
        tilt = self.gyro.tilt(stamp, counts)  # after the gyro's wait: the window's samples are in
        # a turning frame's second pass on the members that measured its patches (None: here)
        refine = None if report is None else MemberRefine.of(
            self.session, grid, prev_level, work, self._job_types, report, stream.dispatcher, self.counters,
            self.settings.refine_on_members_pixels, stream.refine_chooser,
        )  # fmt: skip
        stream.state, core = stream.tracker.conclude(
            stream.state, frame.pixels, measurement, stamp, gyro, refine, tilt
        )
        stream.prev_level, stream.prev_seq = level, frame.seq
        t_end = time.perf_counter()
        self._last_shares = plan.shares()
        members = report.members if report else {SELF: grid.n_patches}
        timings = {
            "total": (t_end - t0) * 1e3,
            "level": (t_level - t0) * 1e3,
            "round": (t_round - t_level) * 1e3,
            "conclude": (t_end - t_round) * 1e3,
        }
        if report is not None:
            timings["self"] = report.self_s * 1e3
        dropped = self.slot.dropped + self.intake.inbox.dropped
        return measured_estimate(self.settings.uav, frame, core, timings, members, report, dropped)
