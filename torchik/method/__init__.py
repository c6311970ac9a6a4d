"""The method: what the paper defines, and nothing that reads files or parses arguments.

so3 (rotations), kinematics (a URDF compiled to tensors), dynamics (the forces that produce a
motion, beyond the paper), models (Human66, Human48, iCub), targets, residual, limits, task (the
normal equations), qp (the QP backends), integrate, state, tracker (`DynamicalIK`, one solve per
step), baselines (the instantaneous IK it is compared with), metrics (MNTE, angular-velocity RMSE).
"""
