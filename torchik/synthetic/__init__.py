"""Generated data with ground truth: smooth motions with exact velocities (`motion.py`) and the
built-in t-pose, walking and running scenarios on any model (`scenarios.py`)."""
