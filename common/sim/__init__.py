"""Ground simulator: a downward camera over a textured plane, an IMU and a rangefinder.

Modules: the camera is :mod:`common.camera`; :mod:`~common.sim.ground` (noise-carpet texture and exact
homography rendering), :mod:`~common.sim.trajectory` (continuous-time poses with analytic derivatives),
:mod:`~common.sim.sensors` (IMU, rangefinder, image degradation), :mod:`~common.sim.flight` (the paper
flights: :func:`~common.sim.flight.hover_flight`, :func:`~common.sim.flight.turns_flight`).
"""
