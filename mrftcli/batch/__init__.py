"""Many logs at once: discovery, per-log settings, local processes or Dask, resume, the fleet summary."""

from .inputs import BatchConfig, LogSettings, discover_logs, load_config
from .run import BatchFailedError, BatchResult, run_batch

__all__ = ["run_batch", "BatchResult", "BatchFailedError", "discover_logs", "load_config", "BatchConfig",
           "LogSettings"]
