"""Model tracker: the particle filter of paper B made to work without external odometry.

State in, state out (:class:`TrackerState`); one call per frame::

    tracker = ModelTracker(scene, camera, TrackerSettings())
    state = tracker.start(initial_pose)                       # a CameraPose; spreads from the scene scale
    state = tracker.step(state, edges, dt_s, rng)             # edges = tracker.edges(image)
    state.pose, state.covariance, state.status                # estimate, 6x6 (position, error angles)

Per frame:

1. **Motion model** (:meth:`ModelTracker.predict`, :mod:`~common.localization.motion`): a constant-velocity
   Kalman filter on the pose (white acceleration / angular acceleration noise in physical units) carries the
   estimate; the particles move with its velocity and rate plus the **process noise**, set in pixels of
   image motion per frame and turned into pose units by the model's size and distance, the focal length and
   the frame interval measured from the stamps, adapted online to the motion model's residual, bounded
   (:mod:`~common.localization.process_noise`, the one home of it; ``velocity_noise_m_s`` /
   ``angular_noise_rad_s`` override it). A frame after a gap (skipped frames) is predicted over the elapsed
   intervals, its noise widened alike. Or the particles move with a given odometry. Optionally a gyro
   (``gyro_rad_s``: the camera-frame mean rate over the frame interval) measures the rate.
2. **Annealed weighting** (Deutscher et al. 2000): ``layers`` rounds of weighting with ``exp(beta l)``,
   ``beta`` chosen so that the effective sample size is half the particles (1 on the last layer unless
   that collapses the cloud), resampling and diffusion with a noise that halves per layer. A sharp
   likelihood no longer starves the cloud. Below ``visible_floor`` of the points a good pose showed, a
   pose's log weight is scaled by the points it shows (a sliver of the model cannot win on fractions).
3. **Local refinement** (:mod:`~common.localization.refine`) of the motion model's prediction and of the best
   particle: Gauss-Newton on oriented point-to-edge offsets; the refinement with the longest matched
   outline wins (:func:`~common.localization.refine.match_measures`: a pose shrunk onto the object's
   texture shows a shorter outline, matched in spots). Its pose, with its covariance inflated by
   ``measurement_inflation``, updates the motion model (gated: a refinement that snapped to a parallel edge
   is ridden over; ``max_rejections`` frames in a row make the frame bad, i.e. a search); the filtered pose
   is the estimate.
4. **Loss detection**: the match fraction (same-direction edges within 2.5 px) of the refined pose; below
   ``lost_match``, below ``trust_ratio`` of the running mean of the good frames' match (the match this model
   shows here when right: a relative test, since absolute fractions differ between models, cameras and
   scenes) or with fewer than ``min_point_ratio`` of the points seen at the last good pose, the frame is
   bad. Bad frames switch the status to ``searching`` and restart the search around the last good pose (half
   of it around that pose carried by its last trusted motion to now) with a spread growing by
   ``spread_growth`` per attempt up to ``max_spread_factor`` (then again from 1); after ``lost_frames`` bad
   frames the status is ``lost`` (the search goes on). A search's pose is only taken when it matches at least
   ``recover_ratio`` of the points matched before the loss (clutter fits match a fraction of the model's
   points well, but not many of them); before any trusted frame, ``lost_match`` of the points the start pose
   shows, counted. A bad frame's pose (the cloud's mean) is published with :func:`~common.localization.search.
   untrusted_covariance`: the cloud's spread plus the next search's box and the offset from the last good
   pose, never a tracked frame's. A good search restarts the motion model moving as the camera did since a
   recent last good pose.

Hidden-line removal: sample points hidden by the model's own faces from the predicted pose are not scored
(:func:`~common.localization.visibility.visible_points`).

Start and recovery search ``search_candidates x spread`` poses (:func:`~common.localization.search.
search_candidates`: half uniform in the box ``pose +- spread``, half aimed at the model), half of them about
the last good pose, half about it turned by the 2D chamfer shift (reaching over the box, or the image-motion
ceiling times the frame intervals since the last good pose if more), annealed over ``search_layers`` keeping
``search_keep`` poses per layer. The default position spread scales with the scene: ``position_spread_m =
0.1 d`` where ``d`` is the median depth of the model's points in view (:meth:`ModelTracker.
viewing_distance_m`; from the initial pose, then from every good frame's); angles do not scale.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt

from common.bounds import check_duration
from common.errors import InputError
from common.localization.motion import (
    MotionState,
    motion_predict,
    motion_rate_update,
    motion_start,
    motion_update,
)
from common.localization.particle_filter import low_variance_resample
from common.localization.pose import (
    CameraPose,
    mean_rotation,
    perturb,
    rotation_vectors,
)
from common.localization.process_noise import NoiseState, adapt, ceiling_px, residual_px
from common.localization.refine import EdgeFit, refine_best
from common.localization.scoring import ImageEdges, with_oriented_distances
from common.localization.search import (
    agreement_inflation,
    anneal,
    cloud_covariance,
    shrunk_covariance,
    twist_covariance_to_world,
    untrusted_covariance,
)
from common.localization.tracker_state import TrackerState, TrackingStatus, next_spread
from common.localization.tracker_views import TrackerViews
from common.types import FloatArray

#: rows of the pose (centre, error angles) in the motion model's 12-D error state
_POSE_BLOCK = np.ix_([0, 1, 2, 6, 7, 8], [0, 1, 2, 6, 7, 8])


class ModelTracker(TrackerViews):
    """Tracker against a known model; holds only immutable precomputed data (no tracking state)."""

    def start(self, pose: CameraPose) -> TrackerState:
        """A state whose first frame searches around ``pose``."""
        n = self.config.n_particles
        return TrackerState(
            positions_m=np.repeat(pose.p_world_camera_m[None], n, axis=0),
            rotations=np.repeat(pose.R_world_camera[None], n, axis=0),
            pose=pose,
            covariance=np.full((6, 6), np.nan),
            velocity_m_s=np.zeros(3),
            angular_rate_rad_s=np.zeros(3),
            status=TrackingStatus.SEARCHING,
            match=0.0,
            last_good=pose,
            distance_m=self.viewing_distance_m(pose),
            expected_points=self._points_in_view(pose),
        )

    # -- prediction -----------------------------------------------------------------------------------
    def predict(
        self,
        state: TrackerState,
        dt_s: float,
        rng: np.random.Generator,
        velocity_m_s: npt.ArrayLike | None = None,
        angular_rate_rad_s: npt.ArrayLike | None = None,
    ) -> TrackerState:
        """Constant velocity and angular rate (the tracker's own, or given odometry) plus process noise."""
        check_duration(dt_s)
        v = state.velocity_m_s if velocity_m_s is None else np.asarray(velocity_m_s, dtype=np.float64)
        w = state.angular_rate_rad_s if angular_rate_rad_s is None else np.asarray(angular_rate_rad_s, float)
        if v.shape != (3,) or w.shape != (3,) or not (np.all(np.isfinite(v)) and np.all(np.isfinite(w))):
            raise InputError("velocity and angular rate must be 3 finite numbers each")
        noise, sigma_p, sigma_r = self.frame_noise(state, dt_s)
        n = state.positions_m.shape[0]
        R_wc = state.pose.R_world_camera  # the noise is set per camera axis (process_noise)
        positions = state.positions_m + v * dt_s + (rng.normal(size=(n, 3)) * sigma_p) @ R_wc.T
        turns = w * dt_s + (rng.normal(size=(n, 3)) * sigma_r) @ R_wc.T
        rotations = perturb(state.rotations, turns)
        motion = state.motion
        if motion is not None:
            motion = motion_predict(
                replace(motion, velocity_m_s=v, angular_rate_rad_s=w), dt_s, self.config.motion
            )
            pose = motion.pose
        else:
            pose = CameraPose(
                state.pose.p_world_camera_m + v * dt_s,
                perturb(state.pose.R_world_camera[None], (w * dt_s)[None])[0],
            )
        return replace(
            state, positions_m=positions, rotations=rotations, pose=pose, motion=motion, process_noise=noise
        )

    # -- one frame ------------------------------------------------------------------------------------
    def step(
        self,
        state: TrackerState,
        edges: ImageEdges,
        dt_s: float,
        rng: np.random.Generator,
        velocity_m_s: npt.ArrayLike | None = None,
        angular_rate_rad_s: npt.ArrayLike | None = None,
        gyro_rad_s: npt.ArrayLike | None = None,
    ) -> TrackerState:
        """Predict (unless a search is pending), weigh (annealed), refine, detect loss, update the motion
        model. ``gyro_rad_s``: the camera-frame angular rate over the frame interval (a gyro's mean, turned
        into the camera frame), a measurement of the motion model's rate (``gyro_sigma_rad_s``)."""
        if edges.width != self.camera.width or edges.height != self.camera.height:
            raise InputError(
                f"image edges are {edges.width}x{edges.height}, "
                f"the camera is {self.camera.width}x{self.camera.height}"
            )
        if edges.gradient_x is None:
            raise InputError("the tracker needs edges with gradients (ModelTracker.edges)")
        cfg = self.config
        spread_m = self.position_spread_m(state.distance_m)
        n = cfg.n_particles
        if state.search_pending:
            if cfg.oriented_search:
                edges = with_oriented_distances(edges)
            centre, positions, rotations = self._search_candidates(state, edges, spread_m, rng, dt_s)
            pos_spread = spread_m * state.spread_factor
            ang_spread = cfg.angle_spread_rad * state.spread_factor
            visible = self._visible(centre)
            state = replace(state, visible=visible, visible_from=centre)
            positions, rotations, logw = anneal(
                self.log_likelihood,
                positions,
                rotations,
                edges,
                rng,
                cfg.search_layers,
                (pos_spread, ang_spread),
                max(n, cfg.search_keep),
                visible,
                coarse=cfg.search_coarseness,
                expected_points=state.expected_points,
            )
        else:
            if gyro_rad_s is not None:
                state, angular_rate_rad_s = self._gyro(state, gyro_rad_s), None
            _, sigma_p, sigma_r = self.frame_noise(state, dt_s)
            state = self.predict(state, dt_s, rng, velocity_m_s, angular_rate_rad_s)
            state = self._refresh_visibility(state)
            visible = state.visible
            noise = (float(sigma_p[0]), float(sigma_r[0]))
            positions, rotations, logw = anneal(
                self.log_likelihood,
                state.positions_m,
                state.rotations,
                edges,
                rng,
                cfg.layers,
                noise,
                n,
                visible,
                expected_points=state.expected_points,
            )
        searching = state.search_pending
        params = (
            cfg.refine
            if searching
            else replace(cfg.refine, iterations=cfg.tracking_iterations, search_px=cfg.tracking_search_px)
        )
        refined, refined_pose = refine_best(
            EdgeFit(self.samples, self.camera, edges, params, visible),
            positions,
            rotations,
            logw,
            cfg.refine_search if searching else cfg.refine_tracking,
            also=() if searching else (state.pose,),
        )
        weights = np.exp(logw - logw.max())
        weights /= weights.sum()
        idx = low_variance_resample(weights, rng, n)
        positions, rotations = positions[idx], rotations[idx]
        positions[0], rotations[0] = refined_pose.p_world_camera_m, refined_pose.R_world_camera
        expected = state.expected_points
        matched = refined.match_fraction * refined.n_points
        good = refined.match_fraction >= cfg.lost_match and refined.n_points >= cfg.min_point_ratio * expected
        if not searching and state.expected_match > 0.0:
            # trusted only near the match this model shows here when right (a relative test: absolute
            # fractions differ between models, cameras and scenes; a wrong pose on texture falls short)
            good = good and refined.match_fraction >= cfg.trust_ratio * state.expected_match
        if searching and state.frames > 0:
            # a search can fit the model to clutter: a recovery must match nearly as many points as the good
            # frames before the loss did, not merely a fraction of what it shows
            good = good and matched >= cfg.recover_ratio * state.expected_matched
        if searching and state.expected_matched == 0.0:
            # acquiring (no trusted frame to compare with): lost_match of the start pose's points, counted
            good = good and matched >= cfg.lost_match * state.expected_points
        mean_R = mean_rotation(rotations, np.ones(n))
        covariance = cloud_covariance(
            positions, rotations, refined_pose if good else CameraPose(positions.mean(0), mean_R)
        )
        pose = refined_pose if good else CameraPose(positions.mean(axis=0), mean_R)
        if good and np.all(np.isfinite(refined.covariance)):
            covariance = covariance + twist_covariance_to_world(refined.covariance, refined_pose)
        frames = state.frames + 1
        fused = None
        if good:
            measured_cov = covariance
            if np.all(np.isfinite(refined.covariance)):
                measured_cov = twist_covariance_to_world(refined.covariance, refined_pose)
            fused = self._fuse(state, refined_pose, measured_cov, searching, dt_s)
            # the images and the motion model disagreeing for max_rejections frames in a row: search (with
            # the recovery test) rather than trust either
            good = not (fused[1] and state.rejected_frames + 1 >= cfg.max_rejections)
        motion = None
        if good and fused is not None:
            motion, rejected, noise_scale = fused
            pose = motion.pose
            covariance = shrunk_covariance(
                motion.covariance[_POSE_BLOCK], cfg.covariance_shrinkage, cfg.covariance_scale
            ) * agreement_inflation(refined.edge_agreement, cfg.agreement_reference, cfg.agreement_power)
            positions[1], rotations[1] = pose.p_world_camera_m, pose.R_world_camera
        # what every frame records, tracked or not
        seen = replace(
            state,
            positions_m=positions,
            rotations=rotations,
            pose=pose,
            covariance=covariance,
            match=refined.match_fraction,
            matched_points=int(matched),
            frames=frames,
            edge_agreement=refined.edge_agreement,
        )
        if motion is not None:
            return replace(
                seen,
                process_noise=self._adapted_noise(state, refined_pose, searching),
                since_good_s=0.0,
                distance_m=self.viewing_distance_m(pose),
                velocity_m_s=motion.velocity_m_s,
                angular_rate_rad_s=motion.angular_rate_rad_s,
                motion=motion,
                noise_scale=noise_scale,
                rejected_frames=state.rejected_frames + 1 if rejected else 0,
                status=TrackingStatus.TRACKING,
                last_good=pose,
                # a slowly fading maximum: a pose that shows only a sliver of the model cannot talk it down
                expected_points=max(int(0.95 * state.expected_points), refined.n_points),
                expected_matched=max(0.95 * state.expected_matched, matched),
                expected_match=(
                    refined.match_fraction
                    if state.expected_match == 0.0
                    else 0.9 * state.expected_match + 0.1 * refined.match_fraction
                ),
                bad_frames=0,
                search_pending=False,
                spread_factor=1.0,
                recoveries=state.recoveries + (1 if state.bad_frames > 0 else 0),
            )
        bad = state.bad_frames + 1
        spread_factor = next_spread(state.spread_factor, cfg) if state.search_pending else 1.0
        box = (spread_m * spread_factor, cfg.angle_spread_rad * spread_factor)
        return replace(
            seen,
            covariance=untrusted_covariance(seen.covariance, pose, state.last_good, box),
            motion=None,  # velocity_m_s / angular_rate_rad_s stay the last trusted motion (searches use it)
            rejected_frames=0,
            status=TrackingStatus.LOST if bad > cfg.lost_frames else TrackingStatus.SEARCHING,
            bad_frames=bad,
            since_good_s=state.since_good_s + dt_s,
            search_pending=True,
            spread_factor=spread_factor,
        )

    def _adapted_noise(self, predicted: TrackerState, measured: CameraPose, searching: bool) -> NoiseState:
        """The process noise after a good frame: adapted to the motion model's residual (px per frame)
        unless the frame was searched (no prediction to compare with)."""
        noise = predicted.process_noise or NoiseState.initial(self.config.noise)
        if searching or noise.last_frames <= 0.0:
            return noise
        r = residual_px(predicted.pose, measured, self.samples.centres_world_m, self.camera)
        return adapt(noise, r / max(noise.last_frames, 1.0), self.config.noise)

    def _gyro(self, state: TrackerState, gyro_rad_s: npt.ArrayLike) -> TrackerState:
        """The state with its angular rate measured by the gyro (camera frame, rad/s)."""
        gyro = np.asarray(gyro_rad_s, dtype=np.float64)
        if gyro.shape != (3,) or not np.all(np.isfinite(gyro)):
            raise InputError("gyro_rad_s must be 3 finite numbers")
        rate_world = state.pose.R_world_camera @ gyro
        if state.motion is None:
            return replace(state, angular_rate_rad_s=rate_world)
        motion = motion_rate_update(state.motion, rate_world, self.config.gyro_sigma_rad_s)
        return replace(state, motion=motion, angular_rate_rad_s=motion.angular_rate_rad_s)

    def _fuse(
        self, state: TrackerState, measured: CameraPose, covariance: FloatArray, searching: bool, dt_s: float
    ) -> tuple[MotionState, bool, float]:
        """The motion model updated with a good frame's pose (restarted there after a search), whether the
        gate rejected it, and the new
        noise scale: the refinement's covariance is scaled by ``measurement_inflation x noise_scale``, where
        ``noise_scale`` follows the normalised innovations (their mean should be 6; geometric steps of
        ``noise_adaptation``, within [1, ``max_noise_scale``]): images whose edges mislead the refinement in
        ways its covariance does not show (repeated structure, low resolution) are trusted less."""
        cfg = self.config
        measured_cov = covariance * (cfg.measurement_inflation * state.noise_scale)
        if state.motion is None or searching:
            # moving as from the last good pose when that is recent (a search fixes a pose, not a motion:
            # at 5 fps a camera at rest after a search is 40 px off on the next frame), else at rest; the
            # velocity as uncertain as the ceiling of the image motion allows
            start = motion_start(
                measured, measured_cov, *self.start_rates(state), *self._recent_motion(state, measured, dt_s)
            )
            return start, False, state.noise_scale
        update = motion_update(state.motion, measured, measured_cov, cfg.motion)
        scale = state.noise_scale
        if not update.rejected:
            step = (max(update.nis, 1e-3) / 6.0) ** cfg.noise_adaptation
            scale = float(np.clip(scale * step, 1.0, cfg.max_noise_scale))
        return update.state, update.rejected, scale

    def _recent_motion(
        self, state: TrackerState, measured: CameraPose, dt_s: float
    ) -> tuple[FloatArray | None, FloatArray | None]:
        """Velocity and world-frame rate from the last good pose to ``measured`` when it was at most
        ``max_gap_frames`` frame intervals ago and the move lies within the image-motion ceiling for that
        time; (None, None) otherwise (the first frame, a long loss, a jump)."""
        noise = state.process_noise
        elapsed = state.since_good_s + dt_s
        if state.frames == 0 or noise is None or noise.frame_interval_s is None or elapsed <= 0.0:
            return None, None
        frames = elapsed / noise.frame_interval_s
        if frames > self.config.noise.max_gap_frames:
            return None, None
        last = state.last_good
        move_px = residual_px(last, measured, self.samples.centres_world_m, self.camera)
        if move_px > ceiling_px(self.config.noise, noise.frame_interval_s) * frames:
            return None, None
        turn = rotation_vectors((measured.R_world_camera @ last.R_world_camera.T)[None])[0]
        return (measured.p_world_camera_m - last.p_world_camera_m) / elapsed, turn / elapsed
