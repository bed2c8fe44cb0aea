"""``capataz record``: every message on ``capataz/**`` into an MCAP file (common/recordings/mcap.py)."""

from services.tools.record.service import RecordService, RecordSettings, register

__all__ = ["RecordService", "RecordSettings", "register"]
