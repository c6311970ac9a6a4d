"""Cohorts: a whole study's recordings tracked in batches on a Dask cluster, one table at the end.

- `manifest.py`: the trials (CSV or TOML), checked before any work;
- `plan.py`: batches of one topology and similar length;
- `trial.py`: a batch on a worker: read, track together, write each trial whole;
- `run.py`: the batches as Dask tasks, resuming, workers that die;
- `summary.py`: the summary table (CSV, Parquet) rebuilt from the trials on disk;
- `synthetic.py`: a generated cohort to try it on;

`torchik cohort` is `torchik/cli/cohort.py`.

Dask is imported only when a cohort runs.
"""

from .manifest import ManifestError, TrialSpec, read_manifest
from .run import CohortRun, run_cohort
from .synthetic import write_synthetic_cohort

__all__ = ["ManifestError", "TrialSpec", "read_manifest", "CohortRun", "run_cohort",
           "write_synthetic_cohort"]
