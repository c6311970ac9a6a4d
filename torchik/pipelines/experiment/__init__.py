"""`torchik experiment paper`: the paper's comparison of dynamical IK with instantaneous IK.

On the same data, three models (Human66, Human48, and iCub through the human-to-iCub map) track
three motions (a held T-pose, walking at 4 km/h, running at 10 km/h) with four methods:

- whole-body instantaneous IK (`WholeBodyIK`: constrained Gauss-Newton to convergence every step);
- pair-wise instantaneous IK (`PairwiseIK`: one small problem per pair of adjacent targets);
- dynamical IK (`DynamicalIK`), in the paper's literal discretisation and in the default
  second-order one ('midpoint').

The data are one person's: the built-in scenarios generated on Human66 (the full human model),
read by Human66 and Human48 as they are and by iCub through `models/maps/human_to_icub.toml`,
or recordings given with --data (through --map first when their segments are not the human
models' links). Human48 (fewer axes, clinical limits) and iCub (another body) cannot reach every
target: their errors have a floor that any method meets at best.

Every method starts from the same state (the zero configuration, the base at its first target),
uses the same QP backend (default 'batched': torch, one call per QP batch, also the pairs' batch;
PIQP per problem with --backend piqp) on one thread (one subject's problems are too small to gain
from more, and on a shared machine extra threads only wait for each other), gains K the
tracker's default (`TrackerSettings`, 20 1/s). Per-step time is the whole step (the dynamical
step, or all iterations of an instantaneous solve) in processor time of the process: what the
step computes, which other programs on a shared machine do not inflate as they do wall-clock
time (results.csv has the wall-clock times too). Each method runs twice and each step counts
with its faster time, with Python's garbage collector paused (as timeit does): interference from
elsewhere is not the method's. Statistics are taken after the first 2 s, as in the paper.
Velocities of the instantaneous methods are central differences of their solutions; the
midpoint scheme's are centred too.

Outputs in DIR: results.csv and results.md (the table, the ratios of dynamical to instantaneous
IK and where the paper's expected shape holds), box_mnte.png, box_rmse.png, box_time.png (per
model, scenario and method), convergence.png (MNTE from the zero configuration to a static T-pose
for several gains, one beyond the stability bound K dt < 2), phase_plane.png (an iCub elbow's
angle and rate with the tanh velocity bounds).

The modules, in the order the experiment uses them:

- `cases.py`: `Settings`, and the cases (`scenario_cases`, `data_cases`): one model, one motion;
- `runs.py`: `METHODS`, `run_method` and `timed_run` (one method on one case, timed step by step),
  `convergence` (to a static T-pose, several gains);
- `tables.py`: `statistics` (one row per run), `ratios`, results.csv and results.md;
- `figures.py`: the five figures;
- `paper.py`: `run_paper`, all of it into one folder (`OUTPUTS`).
"""

from .cases import PERSON, Case, Settings, data_cases, scenario_cases
from .figures import box_plots, convergence_figure, phase_plane_figure
from .paper import OUTPUTS, run_paper
from .runs import CONVERGENCE_GAINS, DYNAMICAL, METHODS, Run, convergence, run_method, static_tpose, timed_run
from .tables import COLUMNS, markdown, ratios, statistics, write_csv

__all__ = ["PERSON", "Case", "Settings", "data_cases", "scenario_cases", "box_plots", "convergence_figure",
           "phase_plane_figure", "OUTPUTS", "run_paper", "CONVERGENCE_GAINS", "DYNAMICAL", "METHODS", "Run",
           "convergence", "run_method", "static_tpose", "timed_run", "COLUMNS", "markdown", "ratios", "statistics",
           "write_csv"]
