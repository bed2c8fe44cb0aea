"""``capataz master``: one per UAV stream; splits each frame among foremen or workers, fits, publishes yaw."""

from services.master.command import register
from services.master.service import MasterService, MasterSettings

__all__ = ["MasterService", "MasterSettings", "register"]
