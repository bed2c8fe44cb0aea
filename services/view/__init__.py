"""``capataz view``: a Foxglove WebSocket server republishing each UAV's stream (services/view/service.py)."""

from services.view.service import ViewService, ViewSettings, register

__all__ = ["ViewService", "ViewSettings", "register"]
