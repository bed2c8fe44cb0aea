"""``capataz view``: a Foxglove WebSocket server republishing each UAV's stream
(services/tools/view/service.py)."""

from services.tools.view.service import ViewService, ViewSettings, register

__all__ = ["ViewService", "ViewSettings", "register"]
