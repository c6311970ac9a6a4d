"""The peer `torchik bench` races one subject against: the dynamical IK step assembled from pinocchio's
kinematics and a QP solver through qpsolvers, as a pinocchio user would write it (a Python loop over
the tracked frames). Its residuals, gains, damping and tanh velocity bounds are torchik's."""

from __future__ import annotations

import numpy as np

from ..errors import optional


class PinocchioTracker:
    """The same dynamical IK step assembled from pinocchio and a QP solver, one subject.

    Velocities are pinocchio's (base twist in the base frame): the same QP up to a rotation of the
    base's variables, which the damping and the joint bounds do not see."""

    def __init__(self, name: str, solver: str, gain: float, damping: float):
        pin = optional("pinocchio", "bench", "torchik bench's per-subject loops (or --no-loops)")

        from ..method.models import TRACKED_LINKS, human_urdf, icub_urdf_path, load_model

        self.pin, self.solver, self.gain, self.damping = pin, solver, gain, damping
        if name == "icub":
            text = open(icub_urdf_path()).read()
        else:
            text = human_urdf(int(name[-2:]))
        self.model = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
        self.data = self.model.createData()
        ours = load_model(name)
        self.links = TRACKED_LINKS[name]
        self.frames = [self.model.getFrameId(link) for link in self.links]
        self.base_frame = self.model.getFrameId(ours.base_link)
        # joint order: ours -> pinocchio's velocity index
        self.joint_v = np.array([self.model.joints[self.model.getJointId(j)].idx_v for j in ours.joint_names])
        self.joint_q = np.array([self.model.joints[self.model.getJointId(j)].idx_q for j in ours.joint_names])
        nv = self.model.nv
        self.lower, self.upper = np.full(nv, -np.inf), np.full(nv, np.inf)
        self.lower[self.joint_v] = ours.lower.numpy()
        self.upper[self.joint_v] = ours.upper.numpy()
        self.A = self.b = None
        if ours.linear_limits is not None:
            self.A = np.zeros((ours.linear_limits.A.shape[0], nv))
            self.A[:, self.joint_v] = ours.linear_limits.A.numpy()
            self.b = ours.linear_limits.b.numpy()
        from ..method.limits import LimitSettings

        limits = LimitSettings()
        self.max_rate, self.limit_gain = limits.max_rate, limits.gain
        self.ours = ours

    def configuration(self, p, R, s) -> np.ndarray:
        q = np.zeros(self.model.nq)
        q[:3] = p
        q[3:7] = self.pin.Quaternion(R).coeffs()  # x, y, z, w
        q[self.joint_q] = s
        return q

    def _bound(self, gap):
        return self.max_rate * np.tanh(self.limit_gain * gap)

    def step(self, q, p_target, v_target, R_targets, w_targets, dt):
        """One step from q (at the targets' instant): the residual against p_target, R_targets, the
        feed-forward v_target, w_targets (torchik's default scheme passes the mean of the two
        samples the step spans). Returns the next configuration."""
        pin, model, data = self.pin, self.model, self.data
        pin.forwardKinematics(model, data, q)
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        frame = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        rows, velocity = [], []
        J_base = pin.getFrameJacobian(model, data, self.base_frame, frame)
        rows.append(J_base[:3])
        velocity.append(v_target + self.gain * (p_target - data.oMf[self.base_frame].translation))
        for f, R_t, w_t in zip(self.frames, R_targets, w_targets):  # the loop a pinocchio user writes
            R_hat = data.oMf[f].rotation
            E = R_hat.T @ R_t
            residual = R_hat @ (0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]]))
            rows.append(pin.getFrameJacobian(model, data, f, frame)[3:])
            velocity.append(w_t + self.gain * residual)
        J, v = np.vstack(rows), np.concatenate(velocity)
        H = J.T @ J + self.damping * np.eye(model.nv)
        g = -J.T @ v
        s = q[self.joint_q]
        lb, ub = self.lower.copy(), self.upper.copy()
        lb[self.joint_v] = np.minimum(-self._bound(s - self.lower[self.joint_v]), self._bound(self.upper[self.joint_v] - s))
        ub[self.joint_v] = self._bound(self.upper[self.joint_v] - s)
        G = h = None
        if self.A is not None:
            norm = np.linalg.norm(self.A, axis=1)
            G, h = self.A, norm * self._bound((self.b - self.A[:, self.joint_v] @ s) / norm)
        import qpsolvers

        nu = qpsolvers.solve_qp(H, g, G, h, lb=lb, ub=ub, solver=self.solver)
        if nu is None:
            raise RuntimeError(f"{self.solver} failed on a step")
        return pin.integrate(model, q, nu * dt)

    def orientation_error(self, q, R_targets) -> float:
        self.pin.framesForwardKinematics(self.model, self.data, q)
        errors = [1 - (np.trace(self.data.oMf[f].rotation.T @ R) - 1) / 2 for f, R in zip(self.frames, R_targets)]
        return float(np.mean(errors))
