"""``capataz worker``: answers PatchJobs on ``capataz/node/{node}/worker/{i}`` with PatchResults."""

from services.worker.service import WorkerService, WorkerSettings, register

__all__ = ["WorkerService", "WorkerSettings", "register"]
