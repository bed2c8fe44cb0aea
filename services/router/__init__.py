"""``capataz router``: a router-mode zenoh session (no zenohd on PyPI) for local runs and compose."""

from services.router.service import RouterService, register

__all__ = ["RouterService", "register"]
