"""Many logs at once: discovery, per-log settings, local processes or Dask, resume, the fleet summary.

:mod:`~mrftcli.batch.inputs` finds the logs and each one's settings, :mod:`~mrftcli.batch.run` analyses
them (one record per log) and :mod:`~mrftcli.batch.summary` makes the fleet table and its outlier flags.
"""

from .inputs import BatchConfig, LogSettings, discover_logs, load_config
from .run import BatchFailedError, BatchOptions, BatchResult, run_batch
from .summary import SUMMARY_COLUMNS, SUMMARY_SCHEMA_VERSION, BatchSummary, flag_outliers

__all__ = ["run_batch", "BatchOptions", "BatchResult", "BatchFailedError", "discover_logs", "load_config", "BatchConfig",
           "LogSettings", "SUMMARY_COLUMNS", "flag_outliers", "BatchSummary", "SUMMARY_SCHEMA_VERSION"]
