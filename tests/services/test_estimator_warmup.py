"""The estimator service builds its filter's compiled kernels before it subscribes: building the filter
compiles them (regression: a cold numba compile under load let the input queues overflow and the filter
diverged in the docker run)."""

from __future__ import annotations

import json
import subprocess
import sys

_PROBE = """
import json, numba
from common.estimation import eskf_kernels
from services.estimator.settings import EstimatorSettings, build_estimator
from services.runtime.camera_options import CameraOptions
# the entry points the filter calls from Python (the private ones are compiled into them)
kernels = {n: getattr(eskf_kernels, n) for n in dir(eskf_kernels) if not n.startswith("_")
           and isinstance(getattr(eskf_kernels, n), numba.core.registry.CPUDispatcher)}
before = sorted(n for n, k in kernels.items() if k.signatures)
build_estimator(EstimatorSettings(camera=CameraOptions(width=160, height=120)))  # as the service does
after = sorted(n for n, k in kernels.items() if k.signatures)
print(json.dumps({"all": sorted(kernels), "before": before, "after": after}))
"""


def test_building_the_estimator_compiles_every_filter_kernel() -> None:
    # a fresh interpreter: in this one, earlier tests may have compiled the kernels already
    done = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    found = json.loads(done.stdout.strip().splitlines()[-1])
    assert {"predict_step", "correct_step", "accelerometer_step"} <= set(found["all"])
    assert found["before"] == []  # nothing is compiled at import
    missing = set(found["all"]) - set(found["after"])
    assert not missing, f"not compiled by building the estimator: {missing}"
