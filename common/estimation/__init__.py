"""Paper C: quaternion + altitude EKF, homography visual odometry, orthogonal rectification, double coupling.

- :mod:`common.estimation.ekf`: :class:`AttitudeAltitudeEkf` (predict eqs. 12-15; updates eq. 16
  accelerometer, eq. 19 yaw as ``[cos, sin]``, eq. 21 rangefinder; chi-square gates), :class:`EkfState`,
  :class:`EkfSettings`.
- :mod:`common.estimation.vo`: Shi-Tomasi + pyramidal LK (forward-backward) + RANSAC homography +
  ``cv2.decomposeHomographyMat`` (Algorithm 2), metric scale and composition (Algorithm 1, eqs. 9-10).
- :mod:`common.estimation.rectify`: warp to the vertical camera at the same centre, valid-region mask (III-C).
- :mod:`common.estimation.buffer`: time-ordered buffer with a bounded lag (multi-rate asynchronous input).
- :mod:`common.estimation.coupling`: :class:`DoubleCouplingEstimator` (EKF <-> VO, sample by sample).
- :mod:`common.estimation.replay`: simulated flights as sample streams, runs and their errors.
"""
