"""Double coupling with a camera that has a lens (issue 26: a stream rig with distortion crashed the
estimator's thread, which took only pinhole cameras). Its frames are resampled onto the pinhole twin where
they enter (:class:`common.camera.PinholeResampling`); on flight (b) seen through a barrel lens the estimate
keeps the pinhole run's bounds (test_coupling_mount's)."""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from common.camera import CameraModel, Distortion, DistortionModel
from common.camera_maps import PinholeResampling, through_lens_maps
from common.errors import InputError
from common.estimation.coupling import DoubleCouplingEstimator
from common.estimation.measurements import FrameMeasurement, Measurement
from common.estimation.replay import camera_model_of, evaluate, run_estimators
from common.sim.flight import Flight
from common.sim.stream import flight_measurements
from tests.common.estimation.test_coupling_mount import START, STOP, _settings


def _with_lens(camera: CameraModel, k1: float, k2: float = 0.0) -> CameraModel:
    return CameraModel(
        width=camera.width, height=camera.height, fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy,
        distortion=Distortion(DistortionModel.RADTAN, (k1, k2, 0.0, 0.0, 0.0)),
    )  # fmt: skip


def _through_lens(lens: CameraModel, pinhole_image: np.ndarray) -> np.ndarray:
    """What ``lens`` sees of a scene its pinhole twin sees as ``pinhole_image`` (as the simulator renders)."""
    return np.asarray(cv2.remap(pinhole_image, *through_lens_maps(lens), cv2.INTER_LINEAR))


def _smooth_image(h: int, w: int, fx: float, fy: float) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.asarray(127.0 + 60.0 * np.sin(u / fx * 9.0) * np.cos(v / fy * 7.0), dtype=np.float64)


@settings(max_examples=20)
@given(k1=st.floats(-0.25, 0.1), k2=st.floats(-0.05, 0.05))
def test_resampling_undoes_the_lens_inside_the_view(k1: float, k2: float) -> None:
    try:
        lens = _with_lens(CameraModel.from_hfov(160, 120, 70.0), k1, k2)
    except InputError:  # a lens whose radial map folds back inside the image is refused by the model
        assume(False)
    scene = _smooth_image(120, 160, lens.fx, lens.fy).astype(np.float32)
    back = PinholeResampling.of(lens).apply(_through_lens(lens, scene))
    inner = (slice(30, 90), slice(40, 120))  # both remaps' borders stay outside for these lenses
    assert np.max(np.abs(back[inner] - scene[inner])) < 1.0


def test_a_camera_without_a_lens_is_not_resampled() -> None:
    estimator = DoubleCouplingEstimator(CameraModel.default())
    assert estimator.lens is None and not estimator.camera.is_distorted


def test_the_estimator_through_a_barrel_lens_keeps_the_pinhole_bounds(flight_b: Flight) -> None:
    pinhole = camera_model_of(flight_b)
    lens = _with_lens(pinhole, -0.12, 0.02)

    def lens_stream() -> Iterator[Measurement]:
        for m in flight_measurements(flight_b, START, STOP):
            yield (
                FrameMeasurement(m.stamp_s, _through_lens(lens, m.image))
                if isinstance(m, FrameMeasurement)
                else m
            )

    through_lens = DoubleCouplingEstimator(lens, flight_b.R_body_camera, settings=_settings(flight_b))
    assert through_lens.lens is not None and through_lens.camera == pinhole
    results = run_estimators({"lens": through_lens}, lens_stream())
    errors = evaluate(results["lens"], flight_b, START)
    assert np.all(errors.att_rmse_deg < 0.5), errors.att_rmse_deg
    assert errors.alt_rmse_m < 0.02, errors.alt_rmse_m
    assert errors.vo_final_error_m < 0.01 and errors.vo_max_error_m < 0.1, errors
    assert through_lens.counters["vo_pairs"] == STOP - START - 1
