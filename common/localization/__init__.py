"""Visual localization against a known 3D model with a particle filter (paper B).

- :mod:`~common.localization.model`: the scene (faces, edges), JSON format, the built-in office;
- :mod:`~common.localization.projection`: edge sample points projected into many particles' cameras at once;
- :mod:`~common.localization.scoring`: image edges and paper B's three scorings (+ distance-transform path);
- :mod:`~common.localization.fused`: the distance-transform scorings' weighting in one compiled pass (numba);
- :mod:`~common.localization.particle_filter`: prediction, weighting, resampling, estimate, re-initialisation;
- :mod:`~common.localization.baseline`: the per-particle loop (the paper's CPU shape; the bench baseline);
- :mod:`~common.localization.tracking`: running the filter over frames, accuracy against ground truth;
- :mod:`~common.localization.pose`: camera poses (no Euler angles inside) and the pose conventions accepted;
- :mod:`~common.localization.visibility`: hidden-line removal (z-buffer of the model's faces);
- :mod:`~common.localization.refine`: oriented-edge Gauss-Newton refinement and the match measure;
- :mod:`~common.localization.tracker`: the tracker without odometry (motion model, annealing, loss, recovery);
- :mod:`~common.localization.cad`: OBJ and ViSP .cao text -> scene;
- :mod:`~common.localization.office`: the built-in office.

Simulated runs live in :mod:`common.sim` (cores do not import the simulator).
"""
