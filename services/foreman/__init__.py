"""``capataz foreman``: splits a master's BlockJob among the workers of its node (same Dispatcher)."""

from services.foreman.service import ForemanService, register

__all__ = ["ForemanService", "register"]
