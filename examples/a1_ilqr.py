"""An iLQR for Unitree A1 standing on four rigid, Baumgarte-stabilised point feet: lower the
trunk by 4 cm and move it 3 cm forward in half a second, with a friction-cone cost on the
contact forces. One solver, two dynamics: grid-gen's kernels (one `grid_gen.load`, no scene
file, no hand-written Lie algebra) and Pinocchio 4.1's (`constraintDynamics`, its
derivatives and `dIntegrate`, composed here into the step). Both give the same iterates;
the script prints each iteration's cost from both, their largest difference, and the time
per iteration of each.

    pip install ./python pin==4.1.0
    python examples/a1_ilqr.py [--iterations N]

`examples/robots/a1.urdf` is example-robot-data's (upstream Unitree's unitree_ros, MPL-2.0).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import grid_gen

URDF = Path(__file__).resolve().parent / "robots" / "a1.urdf"
FEET = ["FR_foot", "FL_foot", "RR_foot", "RL_foot"]
DT, KNOTS = 0.02, 25
# Baumgarte gains per foot, [Kp, Kd] (critically damped): the feet held where they stand.
GAINS = np.array([[100.0, 20.0]] * len(FEET))
MU = 0.6  # friction coefficient of the cone's inner pyramid
# Weights: base position and orientation, joints, velocities, torques, friction violation.
W_BASE, W_JOINT, W_V, W_U, W_FRICTION, W_TERMINAL = 1e3, 1.0, 0.1, 1e-3, 1.0, 10.0

# The friction pyramid per foot, C λ <= 0: |λx|, |λy| <= μ λz, and λz >= 0.
CONE = np.array([[1, 0, -MU], [-1, 0, -MU], [0, 1, -MU], [0, -1, -MU], [0, 0, -1.0]])


def standing(nq: int, joint_names, lower: float = 0.0, forward: float = 0.0) -> np.ndarray:
    """The SRDF's standing pose (thigh 0.8, calf -1.5), the trunk moved."""
    q = np.zeros(nq)
    q[:7] = [forward, 0.0, 0.30 - lower, 0.0, 0.0, 0.0, 1.0]
    for k, name in enumerate(joint_names[6:]):
        q[7 + k] = 0.8 if "thigh" in name else -1.5 if "calf" in name else 0.0
    return q


class GridGenDynamics:
    """The step, its linearisation and λ, and the configuration space's difference, all
    from one grid-gen library."""

    name = "grid-gen"

    def __init__(self):
        self.robot = grid_gen.load(
            URDF,
            floating_base=True,
            contacts={f: "point" for f in FEET},
            step="semi_implicit_euler",
            dt=DT,
            baumgarte=True,
            frames=FEET,
            kernels=["step", "step_grad", "integrate", "difference", "ddifference", "frame_placement"],
        )
        r = self.robot
        self.nq, self.nv, self.nu, self.joint_names = r.nq, r.nv, r.nu, r.joint_names

    def hold(self, q):
        self.refs = self.robot.frame_placement(q).translation.copy()

    def step(self, q, v, u):
        r = self.robot.step(q, v, u, gains=GAINS, contact_ref=self.refs)
        return r.q_next, r.qd_next, r.lam

    def step_grad(self, Q, V, U):
        """A, B, λ, ∂λ/∂x, ∂λ/∂u at every knot, in one batched call."""
        r = self.robot.step_grad(Q, V, U, gains=GAINS, contact_ref=self.refs)
        return r.A, r.B, r.lam, r.dlam_dx, r.dlam_du

    def difference(self, q0, q1, jacobian=True):
        """q1 ⊖ q0 and its Jacobian with respect to q1 (batched)."""
        d = self.robot.difference(q0, q1)
        return d, self.robot.ddifference(q0, q1).dq1 if jacobian else None


class PinocchioDynamics:
    """The same quantities from Pinocchio: constraintDynamics with the corrector,
    computeConstraintDynamicsDerivatives and the semi-implicit step composed with
    integrate and dIntegrate, knot by knot. Pinocchio orders a joint's children by name,
    grid-gen as the URDF lists them: vectors and matrices are mapped by joint name."""

    name = "Pinocchio"

    def __init__(self, joint_names):
        import pinocchio as pin

        self.pin = pin
        self.model = pin.buildModelFromUrdf(str(URDF), pin.JointModelFreeFlyer())
        self.data = self.model.createData()
        m = self.model
        # Pinocchio's index of each of grid-gen's coordinates and q entries.
        self.pv, self.pq = list(range(6)), list(range(7))
        for name in joint_names[6:]:
            joint = m.joints[m.getJointId(name)]
            self.pv.append(joint.idx_v)
            self.pq.append(joint.idx_q)
        self.pv2 = self.pv + [m.nv + i for i in self.pv]
        self.nq, self.nv, self.joint_names = m.nq, m.nv, list(joint_names)
        self.prox = pin.ProximalSettings(1e-14, 1e-12, 1)

    def hold(self, q):
        pin, m, d = self.pin, self.model, self.data
        q = self._in(q, np.zeros(self.nv))[0]
        pin.framesForwardKinematics(m, d, q)
        self.cms, self.cds = pin.StdVec_RigidConstraintModel(), pin.StdVec_RigidConstraintData()
        for k, name in enumerate(FEET):
            frame = m.frames[m.getFrameId(name, pin.BODY)]
            ref = pin.SE3(np.eye(3), d.oMf[m.getFrameId(name, pin.BODY)].translation.copy())
            cm = pin.RigidConstraintModel(pin.ContactType.CONTACT_3D, m, frame.parentJoint, frame.placement, 0, ref, pin.LOCAL_WORLD_ALIGNED)
            bp = cm.m_baumgarte_parameters
            bp.Kp, bp.Kd = GAINS[k]
            cm.setBaumgarteCorrectorParameters(bp)
            self.cms.append(cm)
            self.cds.append(cm.createData())
        pin.initConstraintDynamics(m, d, self.cms, self.cds)

    def _in(self, q, v, u=None):
        """grid-gen's q, v (and actuated τ) in Pinocchio's order."""
        qp, vp = np.empty(self.nq), np.empty(self.nv)
        qp[self.pq], vp[self.pv] = q, v
        if u is None:
            return qp, vp
        tau = np.zeros(self.nv)
        tau[self.pv[6:]] = u
        return qp, vp, tau

    def _dynamics(self, q, v, tau):
        a = self.pin.constraintDynamics(self.model, self.data, q, v, tau, self.cms, self.cds, self.prox)
        return a.copy(), self.data.lambda_c.copy()

    def step(self, q, v, u):
        q, v, tau = self._in(q, v, u)
        a, lam = self._dynamics(q, v, tau)
        v1 = v + DT * a
        return self.pin.integrate(self.model, q, DT * v1)[self.pq], v1[self.pv], lam

    def step_grad(self, Q, V, U):
        pin, m, d, nv = self.pin, self.model, self.data, self.nv
        A, B, L, LX, LU = [], [], [], [], []
        for q, v, u in zip(Q, V, U):
            q, v, tau = self._in(q, v, u)
            a, lam = self._dynamics(q, v, tau)
            pin.computeConstraintDynamicsDerivatives(m, d, self.cms, self.cds)
            da_dx = np.hstack([d.ddq_dq, d.ddq_dv])
            da_du = d.ddq_dtau[:, self.pv[6:]]
            dl_dx = np.hstack([d.dlambda_dq, d.dlambda_dv])[:, self.pv2]
            dl_du = d.dlambda_dtau[:, self.pv[6:]]
            v1 = v + DT * a
            jq = pin.dIntegrate(m, q, DT * v1, pin.ARG0)
            jv = pin.dIntegrate(m, q, DT * v1, pin.ARG1)
            dv1_dx = np.hstack([np.zeros((nv, nv)), np.eye(nv)]) + DT * da_dx
            dq1_dx = np.hstack([jq, np.zeros((nv, nv))]) + DT * jv @ dv1_dx
            A.append(np.vstack([dq1_dx, dv1_dx])[np.ix_(self.pv2, self.pv2)])
            B.append(np.vstack([DT * DT * jv @ da_du, DT * da_du])[self.pv2])
            L.append(lam)
            LX.append(dl_dx)
            LU.append(dl_du)
        return np.array(A), np.array(B), np.array(L), np.array(LX), np.array(LU)

    def difference(self, q0, q1, jacobian=True):
        pin, m, pv = self.pin, self.model, self.pv
        pairs = [(self._in(a, np.zeros(self.nv))[0], self._in(b, np.zeros(self.nv))[0]) for a, b in zip(q0, q1)]
        d = np.array([pin.difference(m, a, b)[pv] for a, b in pairs])
        if not jacobian:
            return d, None
        j = np.array([pin.dDifference(m, a, b, pin.ARG1)[np.ix_(pv, pv)] for a, b in pairs])
        return d, j


class Timed:
    """A dynamics whose step, step_grad and difference calls are timed."""

    def __init__(self, dyn):
        self.dyn, self.seconds = dyn, 0.0

    def __getattr__(self, name):
        attr = getattr(self.dyn, name)
        if name not in ("step", "step_grad", "difference"):
            return attr

        def timed(*args):
            start = time.perf_counter()
            try:
                return attr(*args)
            finally:
                self.seconds += time.perf_counter() - start

        return timed


def weights(nv: int) -> np.ndarray:
    return np.concatenate([[W_BASE] * 6, [W_JOINT] * (nv - 6), [W_V] * nv])


class Problem:
    """Costs and their Gauss-Newton derivatives: the state's distance to the target on the
    manifold, torques near those that hold the robot up, and the friction pyramid's
    violation by each foot's force."""

    def __init__(self, dyn, q0):
        self.dyn, self.nv = dyn, dyn.nv
        self.q0 = q0
        self.q_ref = standing(dyn.nq, dyn.joint_names, lower=0.04, forward=0.03)
        self.w = weights(self.nv)

    def state_terms(self, Q, V):
        """Residual r = [q ⊖ q_ref; v] and its Jacobian in the tangent space, per knot."""
        n = len(Q)
        d, j = self.dyn.difference(np.broadcast_to(self.q_ref, (n, self.dyn.nq)), Q)
        r = np.hstack([d, V])
        jac = np.zeros((n, 2 * self.nv, 2 * self.nv))
        jac[:, : self.nv, : self.nv] = j
        jac[:, self.nv :, self.nv :] = np.eye(self.nv)
        return r, jac

    def cost(self, Q, V, U, L):
        r, _ = self.state_terms(Q, V)
        s = 0.5 * np.einsum("ti,i,ti->", r[:-1], self.w, r[:-1]) + 0.5 * W_TERMINAL * r[-1] @ (self.w * r[-1])
        g = np.maximum(np.einsum("ij,tfj->tfi", CONE, L.reshape(len(L), len(FEET), 3)), 0.0)
        return s + 0.5 * W_U * np.sum(U * U) + 0.5 * W_FRICTION * np.sum(g * g)

    def derivatives(self, Q, V, U, L, LX, LU):
        r, jac = self.state_terms(Q, V)
        wt = np.concatenate([np.full(len(Q) - 1, 1.0), [W_TERMINAL]])[:, None] * self.w
        lx = np.einsum("tji,tj->ti", jac, wt * r)
        lxx = np.einsum("tji,tj,tjk->tik", jac, wt, jac)
        # The friction pyramid on λ, whose rows depend on the knot's x and u.
        T, nf = len(U), len(FEET)
        big = np.zeros((T, 5 * nf, 3 * nf))
        for f in range(nf):
            big[:, 5 * f : 5 * f + 5, 3 * f : 3 * f + 3] = CONE
        g = np.einsum("tij,tj->ti", big, L)
        active = (g > 0.0) * W_FRICTION
        gx = np.einsum("tij,tjk->tik", big, LX)
        gu = np.einsum("tij,tjk->tik", big, LU)
        lx[:-1] += np.einsum("tik,ti->tk", gx, active * g)
        lxx[:-1] += np.einsum("tik,ti,til->tkl", gx, active, gx)
        lu = W_U * U + np.einsum("tik,ti->tk", gu, active * g)
        luu = W_U * np.eye(U.shape[1]) + np.einsum("tik,ti,til->tkl", gu, active, gu)
        lux = np.einsum("tik,ti,til->tkl", gu, active, gx)
        return lx, lxx, lu, luu, lux


def rollout(dyn, q0, v0, U, Q_nom=None, V_nom=None, K=None, k=None, alpha=1.0):
    """The trajectory from (q0, v0) under U, or under the feedback policy around a nominal
    one (δx = [q ⊖ q_nom; v − v_nom] by the robot's own difference). Without a policy, a
    joint PD around q0 steadies U: held torques alone let the legs fold (an unstable
    equilibrium, which would make the two solvers' first rollouts part by the rounding
    of their dynamics, amplified e^(40/s · 0.5 s))."""
    T = len(U)
    Q, V, L, U_new = [q0], [v0], [], []
    for t in range(T):
        u = U[t]
        if K is None:
            u = u - 10.0 * (Q[t][7:] - q0[7:]) - 0.5 * V[t][6:]
        else:
            dq, _ = dyn.difference(Q_nom[t][None], Q[t][None], False)
            dx = np.concatenate([dq[0], V[t] - V_nom[t]])
            u = U[t] + alpha * k[t] + K[t] @ dx
        q, v, lam = dyn.step(Q[t], V[t], u)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            # A step too long for the line search: the caller tries a shorter one.
            return None
        Q.append(q)
        V.append(v)
        L.append(lam)
        U_new.append(u)
    return np.array(Q), np.array(V), np.array(U_new), np.array(L)


def ilqr(dyn, iterations: int):
    dyn = Timed(dyn)
    q0 = standing(dyn.nq, dyn.joint_names)
    v0 = np.zeros(dyn.nv)
    dyn.hold(q0)
    problem = Problem(dyn, q0)
    # Start from the torques that hold the robot still at q0: q̇⁺ is affine in u at a fixed
    # state, so one least-squares step on B's velocity rows zeroes it.
    u = np.zeros(dyn.nq - 7)
    _, v1, _ = dyn.step(q0, v0, u)
    B = dyn.step_grad(q0[None], v0[None], u[None])[1][0]
    # The feet's internal forces make B's rows rank 6 of 12: the minimum-norm solution, with
    # singular values below 1e-8 of the largest (rounding's, in either backend) cut.
    u = u - np.linalg.lstsq(B[dyn.nv :], v1, rcond=1e-8)[0]
    Q, V, U, L = rollout(dyn, q0, v0, np.tile(u, (KNOTS, 1)))
    cost = problem.cost(Q, V, U, L)
    costs, times, reg = [cost], [], 1e-6
    for _ in range(iterations):
        start, spent = time.perf_counter(), dyn.seconds
        A, B, L, LX, LU = dyn.step_grad(Q[:-1], V[:-1], U)
        lx, lxx, lu, luu, lux = problem.derivatives(Q, V, U, L, LX, LU)
        vx, vxx = lx[-1], lxx[-1]
        K, k = np.zeros((KNOTS, B.shape[2], A.shape[1])), np.zeros((KNOTS, B.shape[2]))
        for t in reversed(range(KNOTS)):
            qx = lx[t] + A[t].T @ vx
            qu = lu[t] + B[t].T @ vx
            qxx = lxx[t] + A[t].T @ vxx @ A[t]
            quu = luu[t] + B[t].T @ vxx @ B[t] + reg * np.eye(B.shape[2])
            qux = lux[t] + B[t].T @ vxx @ A[t]
            K[t] = -np.linalg.solve(quu, qux)
            k[t] = -np.linalg.solve(quu, qu)
            vx = qx + K[t].T @ quu @ k[t] + K[t].T @ qu + qux.T @ k[t]
            vxx = qxx + K[t].T @ quu @ K[t] + K[t].T @ qux + qux.T @ K[t]
            vxx = 0.5 * (vxx + vxx.T)
        for alpha in [1.0, 0.5, 0.25, 0.125, 0.0625]:
            trial = rollout(dyn, q0, v0, U, Q, V, K, k, alpha)
            if trial is None:
                continue
            Qn, Vn, Un, Ln = trial
            new = problem.cost(Qn, Vn, Un, Ln)
            if new < cost:
                Q, V, U, L, cost = Qn, Vn, Un, Ln, new
                reg = max(reg / 10.0, 1e-9)
                break
        else:
            # No step decreased the cost: more regularisation, a shorter step next time.
            reg *= 100.0
        times.append((time.perf_counter() - start, dyn.seconds - spent))
        costs.append(cost)
    return costs, times, (Q, V, U, L)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=8)
    args = parser.parse_args()
    ours = GridGenDynamics()
    theirs = PinocchioDynamics(ours.joint_names)
    runs = {d.name: ilqr(d, args.iterations) for d in (ours, theirs)}
    (c0, t0, x0), (c1, t1, x1) = runs["grid-gen"], runs["Pinocchio"]
    print(f"A1, {KNOTS} knots of {DT} s, four Baumgarte-stabilised point feet, friction pyramid mu = {MU}")
    print("iteration  cost (grid-gen)        cost (Pinocchio)       relative difference")
    for i, (a, b) in enumerate(zip(c0, c1)):
        print(f"{i:9d}  {a:.15e}  {b:.15e}  {abs(a - b) / abs(b):.1e}")
    trajectory = max(float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300)) for a, b in zip(x0, x1))
    feet = ours.robot.frame_placement(x0[0]).translation - ours.refs
    print(f"largest relative difference of the final trajectories (q, v, u, lambda): {trajectory:.1e}")
    print(f"feet drift from their references over the plan: {np.max(np.linalg.norm(feet, axis=-1)) * 1e3:.3f} mm")
    # Medians over the iterations: the whole iteration (the NumPy backward pass and cost
    # derivatives, the same code for both), and within it the dynamics calls alone.
    for what, k in (("time per iteration", 0), ("of which dynamics calls", 1)):
        a, b = np.median([t[k] for t in t0]), np.median([t[k] for t in t1])
        print(f"{what} (median): grid-gen {a * 1e3:.1f} ms, Pinocchio {b * 1e3:.1f} ms ({b / a:.1f}x)")
    worst = max(abs(a - b) / abs(b) for a, b in zip(c0, c1))
    assert worst < 1e-8, f"the two solvers' costs differ by {worst:.1e}"
    assert c0[-1] < 0.5 * c0[0], "the solver made progress"


if __name__ == "__main__":
    main()
