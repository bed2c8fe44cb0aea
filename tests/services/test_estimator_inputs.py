"""A decoded message becomes the estimator's checked measurement (``services/estimator/inputs.py``): the yaw
cluster's published variance travels with its yaw."""

from __future__ import annotations

from common.estimation.measurements import YawMeasurement
from common.wire.codec import decode, encode
from common.wire.messages import YawEstimate
from services.estimator.inputs import measurement_of


def test_the_yaw_clusters_published_variance_reaches_the_filters_measurement() -> None:
    sent = YawEstimate(
        uav="uav0", seq=3, stamp_s=12.5, delta_yaw_rad=0.01, yaw_rad=0.4, inlier_count=38, patch_count=40,
        confidence=0.9, low_confidence=False, method="patches", yaw_variance_rad2=3.0e-4,
        delta_variance_rad2=1.0e-6,
    )  # fmt: skip
    received = decode(*encode(sent), YawEstimate)
    assert measurement_of(received, (240, 320)) == YawMeasurement(12.5, 0.4, 3.0e-4)
