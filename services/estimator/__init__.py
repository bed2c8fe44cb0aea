"""``capataz estimator``: EKF + visual odometry with double coupling (paper C) for one UAV's streams."""

from services.estimator.service import EstimatorService, EstimatorSettings, build_estimator, register

__all__ = ["EstimatorService", "EstimatorSettings", "build_estimator", "register"]
