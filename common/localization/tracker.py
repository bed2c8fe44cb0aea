"""Model tracker: the particle filter of paper B made to work without external odometry.

State in, state out (:class:`TrackerState`); one call per frame::

    tracker = ModelTracker(scene, camera, TrackerSettings())
    state = tracker.start(initial_pose)                       # a CameraPose; spreads from the scene scale
    state = tracker.step(state, edges, dt_s, rng)             # edges = tracker.edges(image)
    state.pose, state.covariance, state.status                # estimate, 6x6 (position, error angles)

Per frame:

1. **Motion model** (:meth:`ModelTracker.predict`): constant velocity and angular rate estimated from the
   tracker's own recent estimates (exponentially smoothed), process noise in physical units per second
   (``velocity_noise_m_s``, ``angular_noise_rad_s``: the unmodelled velocity), or a given odometry.
2. **Annealed weighting** (Deutscher et al. 2000): ``layers`` rounds of weighting with ``exp(beta l)``,
   ``beta`` chosen so that the effective sample size is half the particles (1 on the last layer unless
   that collapses the cloud), resampling and diffusion with a noise that halves per layer. A sharp
   likelihood no longer starves the cloud.
3. **Local refinement** of the best particle (:mod:`~common.localization.refine`): Gauss-Newton on oriented
   point-to-edge offsets; the refined pose replaces the worst particle and is the estimate when it matches.
4. **Loss detection**: the match fraction (same-direction edges within 2.5 px) of the estimate; below
   ``lost_match`` (or fewer than ``min_point_ratio`` of the points seen at the last good pose) the frame is
   bad. Bad frames switch the status to ``searching`` and restart the search around the last good pose with
   a spread growing by ``spread_growth`` per attempt up to ``max_spread_factor`` (then again from 1);
   after ``lost_frames`` bad frames the status is ``lost`` (the search goes on).

Hidden-line removal: sample points hidden by the model's own faces from the predicted pose are not scored
(:func:`~common.localization.visibility.visible_points`).

Start and recovery search ``search_candidates`` poses uniformly in the box ``pose +- spread`` (position per
axis, rotation vector per axis), annealed over ``search_layers``. The default spreads and noises scale with
the scene: ``position_spread_m = 0.1 d`` and ``velocity_noise_m_s = 0.2 d / s`` where ``d`` is the median
depth of the model's points in view from the initial pose (:meth:`ModelTracker.viewing_distance_m`); angles
do not scale.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.errors import InputError
from common.localization.model import SceneModel
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
    rotation_angle_rad,
)
from common.localization.projection import EdgeSamples, project_posed_samples, sample_edges
from common.localization.refine import refine_best
from common.localization.scoring import ImageEdges, extract_image_edges, score_particles
from common.localization.search import (
    anneal,
    chamfer_turn,
    cloud_covariance,
    search_candidates,
    twist_covariance_to_world,
)
from common.localization.tracker_state import TrackerSettings, TrackerState, TrackingStatus, next_spread
from common.localization.visibility import visible_points
from common.types import FloatArray

#: rows of the pose (centre, error angles) in the motion model's 12-D error state
_POSE_ROWS = [0, 1, 2, 6, 7, 8]


class ModelTracker:
    """Tracker against a known model; holds only immutable precomputed data (no tracking state)."""

    def __init__(self, scene: SceneModel, camera: CameraModel, config: TrackerSettings | None = None) -> None:
        self.scene = scene
        self.camera = camera
        self.config = config or TrackerSettings()
        self.samples: EdgeSamples = sample_edges(scene, self.config.points_per_edge)

    # -- set-up ---------------------------------------------------------------------------------------
    def edges(self, image: npt.ArrayLike) -> ImageEdges:
        """The frame's edges as the tracker needs them (with gradient directions)."""
        return extract_image_edges(image, with_gradients=True, precise_distance=False)

    def viewing_distance_m(self, pose: CameraPose) -> float:
        """Median depth (m) of the model's sample points in view from ``pose`` (the distance to the model's
        centre when none is in view): the scale of the scene as this camera sees it."""
        pc = (self.samples.points_world_m.reshape(-1, 3) - pose.p_world_camera_m) @ pose.R_world_camera
        z = pc[:, 2]
        ahead = z > 1e-3
        x_n = pc[ahead, 0] / z[ahead]
        y_n = pc[ahead, 1] / z[ahead]
        half_w = self.camera.width / (2.0 * self.camera.fx)
        half_h = self.camera.height / (2.0 * self.camera.fy)
        in_view = (np.abs(x_n) <= half_w) & (np.abs(y_n) <= half_h)
        if in_view.sum() >= 3:
            return float(np.median(z[ahead][in_view]))
        return max(float(np.linalg.norm(pose.p_world_camera_m - self.scene.centre_world_m)), 1e-3)

    def scales(self, distance_m: float) -> tuple[float, float]:
        """Position spread (m) and velocity noise (m/s) for a model ``distance_m`` away (configured or
        scaled: 0.1 d and 0.2 d / s)."""
        cfg = self.config
        spread = cfg.position_spread_m if cfg.position_spread_m is not None else 0.1 * distance_m
        noise = cfg.velocity_noise_m_s if cfg.velocity_noise_m_s is not None else 0.2 * distance_m
        return spread, noise

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
        if not np.isfinite(dt_s) or dt_s < 0.0:
            raise InputError(f"dt_s must be finite and >= 0, got {dt_s}")
        v = state.velocity_m_s if velocity_m_s is None else np.asarray(velocity_m_s, dtype=np.float64)
        w = state.angular_rate_rad_s if angular_rate_rad_s is None else np.asarray(angular_rate_rad_s, float)
        if v.shape != (3,) or w.shape != (3,) or not (np.all(np.isfinite(v)) and np.all(np.isfinite(w))):
            raise InputError("velocity and angular rate must be 3 finite numbers each")
        _, noise_m_s = self.scales(state.distance_m)
        n = state.positions_m.shape[0]
        positions = state.positions_m + v * dt_s + rng.normal(size=(n, 3)) * (noise_m_s * dt_s)
        turns = w * dt_s + rng.normal(size=(n, 3)) * (self.config.angular_noise_rad_s * dt_s)
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
        return replace(state, positions_m=positions, rotations=rotations, pose=pose, motion=motion)

    # -- weighting ------------------------------------------------------------------------------------
    def log_likelihood(
        self,
        positions: FloatArray,
        rotations: FloatArray,
        edges: ImageEdges,
        visible: npt.NDArray[np.bool_] | None,
        coarseness: float = 1.0,
        expected_points: int = 0,
    ) -> FloatArray:
        """log W (P,) of the configured scoring for every pose, in blocks of ``chunk_particles``;
        ``coarseness > 1`` widens its pixel scales (sigma, alignment, maximum normal) for a coarse search.

        Paper B's scorings are fractions of the visible sample points, so a pose that shows only a sliver of
        the model (a few points, all on some edge) scores like one that shows all of it; a search over a wide
        box finds such slivers first. With ``expected_points`` (what a good pose showed), a pose showing
        fewer than ``visible_floor`` of them has its log weight scaled by ``shown / (floor x expected)``:
        counted, not a fraction, below the floor."""
        chunk = max(1, self.config.chunk_particles)
        params = self.config.scoring
        if coarseness != 1.0:
            params = replace(
                params,
                sigma_px=params.sigma_px * coarseness,
                align_px=params.align_px * coarseness,
                max_normal_px=round(params.max_normal_px * coarseness),
            )
        from common.localization.scoring import ScoringMethod  # local: only the method test needs it

        out = []
        for s in range(0, positions.shape[0], chunk):
            R_cw = np.swapaxes(rotations[s : s + chunk], 1, 2)
            proj = project_posed_samples(
                self.samples,
                R_cw,
                positions[s : s + chunk],
                self.camera,
                with_normals=params.method is ScoringMethod.NEAREST_EDGE,
                visible=visible,
            )
            logw = score_particles(proj, edges, params).log_weight
            floor = self.config.visible_floor * expected_points
            if floor > 0.0:
                shown = proj.valid.reshape(proj.valid.shape[0], -1).sum(axis=1)
                logw = logw * np.minimum(shown / floor, 1.0)
            out.append(logw)
        return np.concatenate(out)

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
        spread_m, noise_m_s = self.scales(state.distance_m)
        n = cfg.n_particles
        if state.search_pending:
            centre, positions, rotations = self._search_candidates(state, edges, spread_m, rng)
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
            state = self.predict(state, dt_s, rng, velocity_m_s, angular_rate_rad_s)
            state = self._refresh_visibility(state)
            visible = state.visible
            dt = max(dt_s, 1e-3)
            noise = (noise_m_s * dt, cfg.angular_noise_rad_s * dt)
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
        refined, refined_pose = refine_best(
            self.samples,
            self.camera,
            positions,
            rotations,
            logw,
            edges,
            visible,
            cfg.refine_search if searching else cfg.refine_tracking,
            cfg.refine
            if searching
            else replace(cfg.refine, iterations=cfg.tracking_iterations, search_px=cfg.tracking_search_px),
        )
        weights = np.exp(logw - logw.max())
        weights /= weights.sum()
        idx = low_variance_resample(weights, rng, n)
        positions, rotations = positions[idx], rotations[idx]
        positions[0], rotations[0] = refined_pose.p_world_camera_m, refined_pose.R_world_camera
        expected = state.expected_points
        matched = refined.match_fraction * refined.n_points
        good = refined.match_fraction >= cfg.lost_match and refined.n_points >= cfg.min_point_ratio * expected
        if searching and state.frames > 0:
            # a search can fit the model to clutter: a recovery must match nearly as many points as the good
            # frames before the loss did, not merely a fraction of what it shows
            good = good and matched >= cfg.recover_ratio * state.expected_matched
        mean_R = mean_rotation(rotations, np.ones(n))
        covariance = cloud_covariance(
            positions, rotations, refined_pose if good else CameraPose(positions.mean(0), mean_R)
        )
        pose = refined_pose if good else CameraPose(positions.mean(axis=0), mean_R)
        if good and np.all(np.isfinite(refined.covariance)):
            covariance = covariance + twist_covariance_to_world(refined.covariance, refined_pose)
        frames = state.frames + 1
        if good:
            measured_cov = covariance
            if np.all(np.isfinite(refined.covariance)):
                measured_cov = twist_covariance_to_world(refined.covariance, refined_pose)
            motion, rejected = self._fuse(state, refined_pose, measured_cov, searching)
            pose = motion.pose
            covariance = motion.covariance[np.ix_(_POSE_ROWS, _POSE_ROWS)]
            positions[1], rotations[1] = pose.p_world_camera_m, pose.R_world_camera
            return replace(
                state,
                positions_m=positions,
                rotations=rotations,
                pose=pose,
                covariance=covariance,
                velocity_m_s=motion.velocity_m_s,
                angular_rate_rad_s=motion.angular_rate_rad_s,
                motion=motion,
                rejected_frames=state.rejected_frames + 1 if rejected else 0,
                status=TrackingStatus.TRACKING,
                match=refined.match_fraction,
                matched_points=int(matched),
                last_good=pose,
                # a slowly fading maximum: a pose that shows only a sliver of the model cannot talk it down
                expected_points=max(int(0.95 * state.expected_points), refined.n_points),
                expected_matched=max(0.95 * state.expected_matched, matched),
                bad_frames=0,
                search_pending=False,
                spread_factor=1.0,
                frames=frames,
                recoveries=state.recoveries + (1 if state.bad_frames > 0 else 0),
            )
        bad = state.bad_frames + 1
        return replace(
            state,
            positions_m=positions,
            rotations=rotations,
            pose=pose,
            covariance=covariance,
            velocity_m_s=np.zeros(3),
            angular_rate_rad_s=np.zeros(3),
            motion=None,
            rejected_frames=0,
            status=TrackingStatus.LOST if bad > cfg.lost_frames else TrackingStatus.SEARCHING,
            match=refined.match_fraction,
            matched_points=int(matched),
            bad_frames=bad,
            search_pending=True,
            spread_factor=next_spread(state.spread_factor, cfg) if state.search_pending else 1.0,
            frames=frames,
        )

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

    def _search_candidates(
        self, state: TrackerState, edges: ImageEdges, spread_m: float, rng: np.random.Generator
    ) -> tuple[CameraPose, FloatArray, FloatArray]:
        """A search's centre and candidates: ``search_candidates x spread`` poses, half about the last good
        pose, half about it turned by the chamfer shift (which clutter can mislead)."""
        cfg = self.config
        last = state.last_good if state.frames > 0 else state.pose
        pos_spread = spread_m * state.spread_factor
        ang_spread = cfg.angle_spread_rad * state.spread_factor
        turned = self._image_shift_prior(last, edges, ang_spread + pos_spread / state.distance_m)
        count = int(cfg.search_candidates * max(state.spread_factor, 1.0))
        parts = [
            search_candidates(c, k, pos_spread, ang_spread, state.distance_m, rng)
            for c, k in ((turned, count - count // 2), (last, count // 2))
        ]
        positions = np.concatenate([p for p, _ in parts])
        rotations = np.concatenate([r for _, r in parts])
        return turned, positions, rotations

    def _fuse(
        self, state: TrackerState, measured: CameraPose, covariance: FloatArray, searching: bool
    ) -> tuple[MotionState, bool]:
        """The motion model updated with a good frame's pose (restarted there after a search, or after
        ``max_rejections`` gated frames in a row: then the images, not the model, are right)."""
        cfg = self.config
        measured_cov = covariance * cfg.measurement_inflation
        if state.motion is None or searching or state.rejected_frames >= cfg.max_rejections:
            _, noise_m_s = self.scales(state.distance_m)
            return motion_start(measured, measured_cov, noise_m_s, cfg.angular_noise_rad_s), False
        update = motion_update(state.motion, measured, measured_cov, cfg.motion)
        return update.state, update.rejected

    def _image_shift_prior(self, centre: CameraPose, edges: ImageEdges, turn_rad: float) -> CameraPose:
        """The search centre turned by :func:`~common.localization.search.chamfer_turn` (the model's
        projection shifted to where the image's edges fit it best), or unchanged."""
        projected = project_posed_samples(
            self.samples,
            centre.R_camera_world[None],
            centre.p_world_camera_m[None],
            self.camera,
            visible=self._visible(centre),
        )
        valid = projected.valid[0]
        if valid.sum() < 20:
            return centre
        turn = chamfer_turn(
            projected.u_px[0][valid],
            projected.v_px[0][valid],
            edges,
            self.camera,
            turn_rad,
            cap_px=6.0 * self.config.scoring.sigma_px,
        )
        if turn is None:
            return centre
        return CameraPose(centre.p_world_camera_m, (turn @ centre.R_camera_world).T)

    def _points_in_view(self, pose: CameraPose) -> int:
        """Sample points of the model in view from ``pose`` (culled, inside the image, not hidden)."""
        projected = project_posed_samples(
            self.samples,
            pose.R_camera_world[None],
            pose.p_world_camera_m[None],
            self.camera,
            visible=self._visible(pose),
        )
        return int(projected.valid.sum())

    def _refresh_visibility(self, state: TrackerState) -> TrackerState:
        """Recompute the hidden-line mask when the camera moved by more than 5 % of its distance to the model
        or turned by more than ``visibility_refresh_rad`` since it was computed (what a sample point's
        visibility depends on changes slowly; a coarse buffer is no sharper than that anyway)."""
        if not self.config.hidden_line_removal:
            return state
        last = state.visible_from
        if last is not None and state.visible is not None:
            distance = float(np.linalg.norm(last.p_world_camera_m - self.scene.centre_world_m))
            moved = float(np.linalg.norm(state.pose.p_world_camera_m - last.p_world_camera_m))
            turned = float(rotation_angle_rad(state.pose.R_world_camera, last.R_world_camera))
            if moved <= 0.05 * distance and turned <= self.config.visibility_refresh_rad:
                return state
        return replace(state, visible=self._visible(state.pose), visible_from=state.pose)

    def _visible(self, pose: CameraPose) -> npt.NDArray[np.bool_] | None:
        if not self.config.hidden_line_removal or self.scene.n_faces == 0:
            return None
        return visible_points(
            self.scene, self.samples.points_world_m, pose.R_camera_world, pose.p_world_camera_m, self.camera
        )
