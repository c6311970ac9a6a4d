"""bench: every pipeline of the benchmark runs and tracks, and bad input is refused."""

import pytest

from torchik.cli import main
from torchik.pipelines.bench import run, table


def test_every_pipeline_runs_and_tracks_the_motion():
    pytest.importorskip("pinocchio")
    results = run(models=("human48",), batches=(3,), loop_steps=20, min_seconds=0.5, max_steps=5, progress=False)
    pipelines = {r.pipeline for r in results}
    assert {"torchik batched", "torchik+piqp", "pinocchio+piqp"} <= pipelines
    for r in results:
        assert r.subject_steps_per_second > 0 and r.steps > 0
        # each pipeline follows the walking-like motion from its exact start (MNTE 1e-4: 0.8 degrees)
        assert r.final_mnte < 1e-4, (r.pipeline, r.final_mnte)
    batched = next(r for r in results if r.pipeline == "torchik batched")
    assert batched.batch == 3 and batched.unsolved_fraction == 0.0
    assert "human48" in table(results)


def test_bad_batch_size_is_refused_with_exit_code_2(capsys):
    assert main(["bench", "--batch", "0", "--quiet"]) == 2
    assert "batch sizes must be positive" in capsys.readouterr().err
