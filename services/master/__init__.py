"""``capataz master``: one per UAV stream; splits each frame among foremen or workers, fits, publishes yaw."""

from services.master.service import MasterService, MasterSettings, register

__all__ = ["MasterService", "MasterSettings", "register"]
