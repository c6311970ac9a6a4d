"""Diagnosis of tracked recordings: find the residual, trace it to an effect the model lacks, add it.

    from torchik.diagnosis.loop import diagnose          # the loop: list of Diagnosis, one per recording
    from torchik.diagnosis.report import write           # report.md, figures, calibration, URDF, .rrd
    from torchik.diagnosis.calibration import apply_calibration_file, load_urdf_model   # reuse them

Modules: analysis (residuals and their structure), effect (the contract of an effect and its
score), placement / gyro / joints / position (the candidate effects by family), candidates (all of
them at once), subject (a recording in the loop), elimination (backward elimination), loop, report,
calibration, command (`torchik diagnose`), synthetic (recordings that carry an effect, for tests).
"""
