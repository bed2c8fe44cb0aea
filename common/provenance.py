"""How a published estimate was obtained: shared by the yaw core and the wire (``YawEstimate.provenance``)."""

from __future__ import annotations

from enum import StrEnum


class Provenance(StrEnum):
    """How the delta integrated into a published yaw was obtained."""

    MEASURED = "measured"  # the camera measured it (and it agreed with the prior and the physical limits)
    BRIDGED = "bridged"  # the gyro's rotation bridged a pair the camera could not measure trustworthily
    HELD = "held"  # no gyro: the recent yaw rate was held over the pair
    INITIAL = "initial"  # frame 0 of a stream: yaw 0 by definition
