"""Convex model-predictive control of the ground reaction forces (paper Sec. 6.2, ref. [20]).

Single-rigid-body model of the MIT Cheetah 3 convex MPC (Di Carlo et al., 2018), linearised
about the reference yaw so that the dynamics are linear time-varying:

    state x = [Θ (roll, pitch, yaw), p, ω (world), ṗ, g]  (13, g = -9.81 as a constant state)
    Θ̇ = Rz(ψ)ᵀ ω,   ṗ = v,   ω̇ = I_w⁻¹ Σ r_i × f_i,   v̇ = Σ f_i / m + g·e_z

with f_i the ground reaction force *on the robot* at foot i (world frame) and r_i the foot
position relative to the COM. The continuous system is a chain of integrators (A³ = 0), so the
zero-order-hold discretisation is exact with a truncated series:
A_d = I + A·dt + A²dt²/2,  B_d = (I·dt + A·dt²/2)·B.

The horizon (N_hor = 6, T_pred = 0.03 s; Table 3) is condensed into one dense QP in the foot
forces only; forces of feet in swing (per the gait schedule) are removed from the decision
vector, so they are exactly zero. Constraints: friction pyramid |f_x|, |f_y| ≤ μ f_z and
0 ≤ f_z ≤ f_max. Solved with PIQP (dense or sparse backend, chosen by measurement: see
docs/locomotion.md; the dense backend is the default).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import piqp
from quadmanip.common.rotations import rot_z, skew

NX = 13  # Θ(3) p(3) ω(3) v(3) g(1)
NU = 12  # 4 feet × 3 force components
GRAVITY = 9.81


@dataclass(frozen=True)
class MpcWeights:
    """Diagonal weights of the MPC cost (paper Table 3 names: Q_R, Q_p, Q_ω, Q_ṗ, R_u)."""

    q_theta: tuple[float, float, float] = (5000.0, 5000.0, 5000.0)
    q_p: tuple[float, float, float] = (100000.0, 150000.0, 100000.0)
    q_omega: tuple[float, float, float] = (2.0, 4.0, 3.0)
    q_v: tuple[float, float, float] = (100.0, 100.0, 100.0)
    r_u: float = 0.1


@dataclass(frozen=True)
class MpcParams:
    """Horizon, time step, contact constraints and solver backend."""

    horizon: int = 6
    dt: float = 0.03
    mu: float = 0.5
    f_max: float = 250.0
    backend: str = "dense"
    weights: MpcWeights = field(default_factory=MpcWeights)
    eps_abs: float = 1e-6
    eps_rel: float = 1e-7
    max_iter: int = 60


@dataclass
class MpcSolution:
    """Result of one MPC step: forces on the robot (world frame) and predicted states."""

    forces: np.ndarray  # (horizon, 4, 3)
    predicted: np.ndarray  # (horizon, 12) [Θ, p, ω, v]
    status: str
    step_time_s: float
    solver_time_s: float
    iterations: int

    @property
    def first(self) -> np.ndarray:
        """Forces of the first step (4, 3): what the stance legs apply now."""
        return self.forces[0]


def desired_forces(foot_rel: np.ndarray, contact: np.ndarray, mass: float) -> np.ndarray:
    """Vertical forces (N, 4, 3) near the equal split m·g/n that carry the weight with no
    roll/pitch moment about the COM (least squares when two feet cannot balance it).

    Solved for all horizon steps at once as a ridge-regularised least-squares problem
    min |A f − b|² + ε |f − f₀|² with A = [1; y_i; x_i] over the feet in stance.
    """
    n = contact.shape[0]
    c = contact.astype(float)
    n_st = np.maximum(c.sum(axis=1), 1.0)
    w = mass * GRAVITY
    f0 = c * (w / n_st)[:, None]  # (n, 4)
    a = np.stack([c, foot_rel[:, :, 1] * c, foot_rel[:, :, 0] * c], axis=1)  # (n, 3, 4)
    b = np.zeros((n, 3))
    b[:, 0] = w
    resid = b - np.einsum("kij,kj->ki", a, f0)
    eps = 1e-8
    ata = np.einsum("kij,kil->kjl", a, a) + eps * np.eye(4)[None]
    df = np.linalg.solve(ata, np.einsum("kij,ki->kj", a, resid)[:, :, None])[:, :, 0]
    out = np.zeros((n, 4, 3))
    out[:, :, 2] = np.maximum(f0 + df, 0.0) * c
    return out


class ConvexMpc:
    """Condensed convex MPC for the foot forces, solved with PIQP every call."""

    def __init__(self, params: MpcParams | None = None) -> None:
        self.params = params or MpcParams()
        p = self.params
        if p.horizon < 1 or p.dt <= 0.0:
            raise ValueError("horizon must be ≥ 1 and dt > 0")
        if p.backend not in ("dense", "sparse"):
            raise ValueError(f"unknown PIQP backend {p.backend!r}")
        w = p.weights
        diag = np.concatenate([w.q_theta, w.q_p, w.q_omega, w.q_v, [0.0]])
        self._l_diag = np.tile(diag, p.horizon)  # (N·13,)
        self._r_u = float(w.r_u)
        # Friction pyramid rows for one foot: [fx - μfz ≤ 0, -fx - μfz ≤ 0, fy..., -fy...].
        mu = p.mu
        self._cone = np.array(
            [[1.0, 0.0, -mu], [-1.0, 0.0, -mu], [0.0, 1.0, -mu], [0.0, -1.0, -mu]]
        )
        self._n_solves = 0
        self._cones: dict[int, np.ndarray] = {}

    def _settings(self, solver: piqp.DenseSolver | piqp.SparseSolver) -> None:
        s = solver.settings
        s.eps_abs = self.params.eps_abs
        s.eps_rel = self.params.eps_rel
        s.max_iter = self.params.max_iter
        s.verbose = False
        s.compute_timings = True

    def condensed(
        self,
        x0: np.ndarray,
        foot_rel: np.ndarray,
        mass: float,
        inertia_body: np.ndarray,
        yaw: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return (A_qp (N·13, 13), B_qp (N·13, N·12)) of X = A_qp x0 + B_qp U."""
        p = self.params
        n, dt = p.horizon, p.dt
        rz = rot_z(yaw)
        a = np.zeros((NX, NX))
        a[0:3, 6:9] = rz.T
        a[3:6, 9:12] = np.eye(3)
        a[11, 12] = 1.0
        a2 = a @ a
        ad = np.eye(NX) + a * dt + a2 * (0.5 * dt * dt)
        # Powers A_d^0..A_d^n.
        apow = np.empty((n + 1, NX, NX))
        apow[0] = np.eye(NX)
        for k in range(1, n + 1):
            apow[k] = apow[k - 1] @ ad
        # Continuous B for every step: rows 6:9 = I_w⁻¹ [r]×, rows 9:12 = I/m.
        i_world = rz @ inertia_body @ rz.T
        i_inv = np.linalg.inv(i_world)
        bc = np.zeros((n, NX, NU))
        bc[:, 6:9, :] = (
            (i_inv @ skew(foot_rel).reshape(n * 4, 3, 3))
            .reshape(n, 4, 3, 3)
            .transpose(0, 2, 1, 3)
            .reshape(n, 3, NU)
        )
        bc[:, 9:12, :] = np.tile(np.eye(3) / mass, (1, 4))[None]
        bd = (np.eye(NX) * dt + a * (0.5 * dt * dt)) @ bc  # (n, 13, 12)
        # Block rows by recursion: row i = A_d · row (i−1), plus B_i on the diagonal.
        bqp = np.zeros((n, NX, n * NU))
        bqp[0, :, 0:NU] = bd[0]
        for i in range(1, n):
            bqp[i, :, : i * NU] = ad @ bqp[i - 1, :, : i * NU]
            bqp[i, :, i * NU : (i + 1) * NU] = bd[i]
        aqp = apow[1:].reshape(n * NX, NX)
        return aqp, bqp.reshape(n * NX, n * NU)

    def solve(
        self,
        x0: np.ndarray,
        x_ref: np.ndarray,
        foot_rel: np.ndarray,
        contact: np.ndarray,
        mass: float,
        inertia_body: np.ndarray,
    ) -> MpcSolution:
        """One MPC step.

        x0: (12,) current [Θ, p, ω, v]; x_ref: (N, 12) reference for steps 1..N;
        foot_rel: (N, 4, 3) or (4, 3) foot positions minus COM position (world frame);
        contact: (N, 4) booleans from the gait schedule; mass, inertia_body (3×3, base frame
        about the COM) of the whole robot including the arm and any held object.
        """
        t0 = time.perf_counter()
        p = self.params
        n = p.horizon
        x0 = np.asarray(x0, dtype=float)
        x_ref = np.asarray(x_ref, dtype=float)
        foot_rel = np.asarray(foot_rel, dtype=float)
        if foot_rel.shape == (4, 3):
            foot_rel = np.broadcast_to(foot_rel, (n, 4, 3))
        contact = np.asarray(contact, dtype=bool)
        if x0.shape != (12,) or x_ref.shape != (n, 12) or contact.shape != (n, 4):
            raise ValueError("x0 (12,), x_ref (N, 12), contact (N, 4) expected")
        yaw = float(np.mean(x_ref[:, 2]))
        aqp, bqp = self.condensed(x0, foot_rel, mass, inertia_body, yaw)
        x0a = np.append(x0, -GRAVITY)
        xr = np.concatenate([x_ref, np.full((n, 1), -GRAVITY)], axis=1).reshape(-1)
        # Keep only forces of feet in stance.
        mask = np.repeat(contact.reshape(-1), 3)
        cols = np.flatnonzero(mask)
        forces = np.zeros((n, 4, 3))
        if cols.size == 0:
            pred = (aqp @ x0a).reshape(n, NX)[:, :12]
            dt_step = time.perf_counter() - t0
            return MpcSolution(forces, pred, "no_contact", dt_step, 0.0, 0)
        b = bqp[:, cols]
        lb = b * self._l_diag[:, None]
        hess = b.T @ lb
        hess[np.diag_indices_from(hess)] += self._r_u
        # Paper Sec. 6.2.2: R_u regularises towards a desired GRF that carries the weight
        # (the paper: half of it per foot in two-feet phases, a quarter in four-feet phases).
        # An equal split only balances when the COM is at the feet's centre, so we use the
        # closest split that also has no moment about the COM (see desired_forces()).
        u_des = desired_forces(foot_rel, contact, mass)
        grad = lb.T @ (aqp @ x0a - xr) - self._r_u * u_des.reshape(-1)[cols]
        nf = cols.size // 3
        g_mat = self._cones.get(nf)
        if g_mat is None:
            g_mat = self._cones[nf] = np.asfortranarray(np.kron(np.eye(nf), self._cone))
        h_u = np.zeros(4 * nf)
        x_l = np.full(cols.size, -np.inf)
        x_u = np.full(cols.size, np.inf)
        x_l[2::3] = 0.0
        x_u[2::3] = p.f_max
        t_s = time.perf_counter()
        u, status, iters = self._qp(hess, grad, g_mat, h_u, x_l, x_u)
        solver_time = time.perf_counter() - t_s
        full = np.zeros(n * NU)
        full[cols] = u
        forces = full.reshape(n, 4, 3)
        pred = (aqp @ x0a + bqp @ full).reshape(n, NX)[:, :12]
        return MpcSolution(forces, pred, status, time.perf_counter() - t0, solver_time, iters)

    def _qp(
        self,
        hess: np.ndarray,
        grad: np.ndarray,
        g_mat: np.ndarray,
        h_u: np.ndarray,
        x_l: np.ndarray,
        x_u: np.ndarray,
    ) -> tuple[np.ndarray, str, int]:
        """Solve min ½uᵀHu + gᵀu s.t. Gu ≤ h_u, x_l ≤ u ≤ x_u with the chosen PIQP backend.

        The problem's size changes with the contact schedule, so a new setup is needed when
        it does; otherwise the existing factorisation structure is reused with update().
        """
        if self.params.backend == "dense":
            solver = piqp.DenseSolver()
            self._settings(solver)
            solver.setup(
                np.asfortranarray(hess), grad, None, None, g_mat, None, h_u,
                x_l, x_u,
            )  # fmt: skip
        else:
            import scipy.sparse as sp

            solver = piqp.SparseSolver()
            self._settings(solver)
            solver.setup(
                sp.csc_matrix(np.triu(hess)), grad, None, None, sp.csc_matrix(g_mat), None, h_u,
                x_l, x_u,
            )  # fmt: skip
        st = solver.solve()
        self._n_solves += 1
        res = solver.result
        ok = st == piqp.PIQP_SOLVED
        u = np.asarray(res.x, dtype=float)
        if not np.all(np.isfinite(u)):
            u = np.zeros_like(u)
            ok = False
        return u, ("solved" if ok else str(st)), int(res.info.iter)
