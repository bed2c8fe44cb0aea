"""``capataz record``: every message on ``capataz/**`` into an MCAP file (common/datasets/recording.py)."""

from services.record.service import RecordService, RecordSettings, register

__all__ = ["RecordService", "RecordSettings", "register"]
