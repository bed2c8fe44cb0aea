"""The model tracker's view of its model and camera (:class:`TrackerViews`): the frame's edges, the scale of
the scene, the weighting of many poses, hidden-line masks and the candidates of a search. Holds only
immutable precomputed data; :class:`~common.localization.tracker.ModelTracker` adds the per-frame filter.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.localization.fused import (
    compile_fused_kernel,
    fused_applies,
    fused_edge_sums,
    fused_model,
    score_from_edge_sums,
)
from common.localization.model import SceneModel
from common.localization.pose import CameraPose, perturb, rotation_angle_rad
from common.localization.process_noise import NoiseState, ceiling_px, observe_interval, pixel_scale
from common.localization.projection import (
    EdgeSamples,
    project_pose_samples,
    project_posed_samples,
    sample_edges,
)
from common.localization.scoring import (
    ImageEdges,
    ScoringMethod,
    extract_image_edges,
    orientation_bins,
    score_particles,
)
from common.localization.search import chamfer_turn, search_candidates
from common.localization.tracker_state import TrackerSettings, TrackerState
from common.localization.visibility import visible_points
from common.types import FloatArray


class TrackerViews:
    """Model, camera and settings of a tracker, and what it computes from them without state."""

    def __init__(self, scene: SceneModel, camera: CameraModel, config: TrackerSettings | None = None) -> None:
        self.scene = scene
        self.camera = camera
        self.config = config or TrackerSettings()
        self.samples: EdgeSamples = sample_edges(scene, self.config.points_per_edge)
        #: half the model's bounding-box diagonal: its size as the process noise sees it
        self.model_radius_m = 0.5 * scene.size_m
        self.fused = fused_model(self.samples, camera)  # the samples as the compiled weighting reads them
        if self.config.fused_weighting:
            compile_fused_kernel()  # now, not on the first frame

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

    def position_spread_m(self, distance_m: float) -> float:
        """Start / recovery position spread (m) for a model ``distance_m`` away (configured, or 0.1 d)."""
        cfg = self.config
        return cfg.position_spread_m if cfg.position_spread_m is not None else 0.1 * distance_m

    def frame_noise(self, state: TrackerState, dt_s: float) -> tuple[NoiseState, FloatArray, FloatArray]:
        """This step's process noise (:mod:`~common.localization.process_noise`): the noise state with
        ``dt_s`` observed, and camera-frame standard deviations of position (3,) m and rotation (3,) rad
        over the step; ``velocity_noise_m_s`` / ``angular_noise_rad_s`` override theirs (x ``dt_s``)."""
        cfg = self.config
        noise = state.process_noise or NoiseState.initial(cfg.noise)
        noise = observe_interval(noise, dt_s, cfg.noise)
        scale = pixel_scale(state.distance_m, self.camera, self.model_radius_m)
        position, rotation = scale.sigmas(noise.noise_px * noise.last_frames)
        if cfg.velocity_noise_m_s is not None:
            position = np.full(3, cfg.velocity_noise_m_s * dt_s)
        if cfg.angular_noise_rad_s is not None:
            rotation = np.full(3, cfg.angular_noise_rad_s * dt_s)
        return noise, position, rotation

    def start_rates(self, state: TrackerState) -> tuple[float, float]:
        """Standard deviation of the velocity (m/s) and angular rate (rad/s) when the motion model starts:
        the ceiling (:func:`~common.localization.process_noise.ceiling_px`) per frame interval (the
        reference rate's until measured), or 5x / 2x the overrides."""
        cfg = self.config
        noise = state.process_noise or NoiseState.initial(cfg.noise)
        interval = noise.frame_interval_s or 1.0 / cfg.noise.reference_rate_hz
        scale = pixel_scale(state.distance_m, self.camera, self.model_radius_m)
        ceiling = ceiling_px(cfg.noise, interval)
        v = scale.lateral_m * ceiling / interval
        w = scale.turn_rad * ceiling / interval
        if cfg.velocity_noise_m_s is not None:
            v = 5.0 * cfg.velocity_noise_m_s
        if cfg.angular_noise_rad_s is not None:
            w = 2.0 * cfg.angular_noise_rad_s
        return v, w

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
        out = []
        fused = self.config.fused_weighting and fused_applies(self.camera, edges, params)
        floor = self.config.visible_floor * expected_points
        for s in range(0, positions.shape[0], chunk):
            R_cw = np.swapaxes(rotations[s : s + chunk], 1, 2)
            if fused:
                sums, counts = fused_edge_sums(
                    self.fused, R_cw, positions[s : s + chunk], self.camera, edges, params, visible
                )
                logw = score_from_edge_sums(sums, counts, params)
                shown = counts.sum(axis=1) if floor > 0.0 else None
            else:
                proj = project_posed_samples(
                    self.samples,
                    R_cw,
                    positions[s : s + chunk],
                    self.camera,
                    with_normals=params.method is ScoringMethod.NEAREST_EDGE
                    or edges.oriented_lookup is not None,
                    visible=visible,
                )
                logw = score_particles(proj, edges, params).log_weight
                shown = proj.valid.reshape(proj.valid.shape[0], -1).sum(axis=1) if floor > 0.0 else None
            if shown is not None:
                logw = logw * np.minimum(shown / floor, 1.0)
            out.append(logw)
        return np.concatenate(out)

    def _search_candidates(
        self,
        state: TrackerState,
        edges: ImageEdges,
        spread_m: float,
        rng: np.random.Generator,
        dt_s: float = 0.0,
    ) -> tuple[CameraPose, FloatArray, FloatArray]:
        """A search's centre and candidates: ``search_candidates x spread`` poses, half about the last good
        pose, half about it carried by its motion to now (:meth:`_carried`) and turned by the chamfer shift
        (which clutter can mislead)."""
        cfg = self.config
        last = state.last_good if state.frames > 0 else state.pose
        pos_spread = spread_m * state.spread_factor
        ang_spread = cfg.angle_spread_rad * state.spread_factor
        carried = self._carried(state, last, dt_s)
        reach = max(ang_spread + pos_spread / state.distance_m, self._elapsed_reach_rad(state, dt_s))
        turned = self._image_shift_prior(carried, edges, reach)
        count = int(cfg.search_candidates * max(state.spread_factor, 1.0))
        parts = [
            search_candidates(c, k, pos_spread, ang_spread, state.distance_m, rng)
            for c, k in ((turned, count - count // 2), (last, count // 2))
        ]
        positions = np.concatenate([p for p, _ in parts])
        rotations = np.concatenate([r for _, r in parts])
        return turned, positions, rotations

    def _since_good(self, state: TrackerState, dt_s: float) -> tuple[float, float] | None:
        """The time since the last good pose up to ``max_gap_frames`` frame intervals, and the frame interval
        (s); None before the first good frame or while the interval is unknown."""
        noise = state.process_noise
        if state.frames == 0 or noise is None or noise.frame_interval_s is None:
            return None
        interval = noise.frame_interval_s
        return min(state.since_good_s + dt_s, self.config.noise.max_gap_frames * interval), interval

    def _elapsed_reach_rad(self, state: TrackerState, dt_s: float) -> float:
        """How far (rad) the camera may have turned since the last good pose: the image-motion ceiling per
        frame interval times the intervals since (up to ``max_gap_frames``), at most half the image's
        narrower field of view. A search that trails a camera turning faster than its box grows never
        catches it (at 5 fps a fast flight turns 10 deg a frame)."""
        since = self._since_good(state, dt_s)
        if since is None:
            return 0.0
        elapsed_s, interval_s = since
        f = max(self.camera.fx, self.camera.fy)
        turn = ceiling_px(self.config.noise, interval_s) * (elapsed_s / interval_s) / f
        half_fov = float(np.arctan2(0.5 * min(self.camera.width, self.camera.height), f))
        return float(min(turn, half_fov))

    def _carried(self, state: TrackerState, last: CameraPose, dt_s: float) -> CameraPose:
        """The last good pose moved by the last trusted velocity and rate (kept through bad frames) over the
        time since it, up to ``max_gap_frames`` frame intervals: at 5 fps a camera moves 40 px a frame, and a
        few frames of a sparse view leave the last good pose far behind."""
        since = self._since_good(state, dt_s)
        if since is None:
            return last
        elapsed = since[0]
        return CameraPose(
            last.p_world_camera_m + state.velocity_m_s * elapsed,
            perturb(last.R_world_camera[None], (state.angular_rate_rad_s * elapsed)[None])[0],
        )

    def _image_shift_prior(self, centre: CameraPose, edges: ImageEdges, turn_rad: float) -> CameraPose:
        """The search centre turned by :func:`~common.localization.search.chamfer_turn` (the model's
        projection shifted to where the image's edges fit it best), or unchanged."""
        oriented = edges.oriented_lookup is not None
        projected = project_pose_samples(
            self.samples,
            centre.R_camera_world,
            centre.p_world_camera_m,
            self.camera,
            with_normals=oriented,
            visible=self._visible(centre),
        )
        valid = projected.valid[0]
        if valid.sum() < 20:
            return centre
        bins = None
        if oriented:
            assert projected.normal_u is not None and projected.normal_v is not None
            bins = orientation_bins(projected.normal_u[0][valid], projected.normal_v[0][valid])
        turn = chamfer_turn(
            projected.u_px[0][valid],
            projected.v_px[0][valid],
            edges,
            self.camera,
            turn_rad,
            cap_px=6.0 * self.config.scoring.sigma_px,
            bins=bins,
        )
        if turn is None:
            return centre
        return CameraPose(centre.p_world_camera_m, (turn @ centre.R_camera_world).T)

    def _points_in_view(self, pose: CameraPose) -> int:
        """Sample points of the model in view from ``pose`` (culled, inside the image, not hidden)."""
        projected = project_pose_samples(
            self.samples, pose.R_camera_world, pose.p_world_camera_m, self.camera, visible=self._visible(pose)
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
