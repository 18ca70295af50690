"""Independent truth solver: compressible hyperelasticity on linear (P1) tetrahedra.

Written for the independent test generator (tests/generators/README.md); it shares no code and no
formulation with palpate's own solvers.

Strain energy per unit reference volume (per element; every coefficient may vary per element):

    W(F) = mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2          compressible Neo-Hookean
         + c2 (Ib1 - 3)^2                                     Yeoh second-order term, Ib1 = J^(-2/3) I1

I1 = tr(F^T F), J = det F. At small strain it is linear elasticity with Lame constants (lam, mu).

Assembly is vectorised over elements (numpy einsum), the tangent assembled into a scipy CSR matrix
and solved by a sparse direct factorisation (SuperLU) inside Newton's method with a backtracking
line search on the total potential energy (every load here is conservative: dead surface
tractions, dead body forces, linear springs), and load stepping that halves the increment when
Newton fails.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


class SolveError(RuntimeError):
    pass


def tet_geometry(X: np.ndarray, T: np.ndarray):
    """Signed volumes, shape-function gradients B (ne,4,3) of the reference configuration.
    Tets of negative orientation are reordered (two nodes swapped) in-place on a copy."""
    T = T.copy()
    D = np.stack([X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]], X[T[:, 3]] - X[T[:, 0]]], axis=2)
    det = np.linalg.det(D)
    neg = det < 0
    if neg.any():
        T[neg, 1], T[neg, 2] = T[neg, 2].copy(), T[neg, 1].copy()
        D = np.stack([X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]], X[T[:, 3]] - X[T[:, 0]]], axis=2)
        det = np.linalg.det(D)
    if (det <= 0).any():
        raise SolveError("degenerate tetrahedron in the truth mesh")
    Dinv = np.linalg.inv(D)  # rows = gradients of N1..N3
    B = np.empty((len(T), 4, 3))
    B[:, 1:, :] = Dinv
    B[:, 0, :] = -Dinv.sum(axis=1)
    return T, det / 6.0, B


def boundary_faces(T: np.ndarray):
    """Faces used by exactly one tet, oriented outward (node order gives an outward normal)."""
    faces = np.concatenate([T[:, [1, 2, 3]], T[:, [0, 3, 2]], T[:, [0, 1, 3]], T[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, idx, cnt = np.unique(key, axis=0, return_index=True, return_counts=True)
    return faces[idx[cnt == 1]]


class Material:
    """Per-element coefficients (arrays of length ne)."""

    def __init__(self, mu, lam, c2=None):
        self.mu = np.asarray(mu, float)
        self.lam = np.asarray(lam, float)
        self.c2 = np.zeros_like(self.mu) if c2 is None else np.broadcast_to(np.asarray(c2, float), self.mu.shape).copy()

    @staticmethod
    def from_E_nu(E, nu, ne):
        E = np.broadcast_to(np.asarray(E, float), (ne,))
        mu = E / (2 * (1 + nu))
        lam = E * nu / ((1 + nu) * (1 - 2 * nu))
        return Material(mu, lam)


def energy_density(F, mat: Material):
    J = np.linalg.det(F)
    if (J <= 0).any():
        return None
    I1 = np.einsum("eij,eij->e", F, F)
    lnJ = np.log(J)
    W = 0.5 * mat.mu * (I1 - 3) - mat.mu * lnJ + 0.5 * mat.lam * lnJ**2
    if mat.c2.any():
        Ib = J ** (-2.0 / 3.0) * I1
        W = W + mat.c2 * (Ib - 3) ** 2
    return W


def stress_tangent(F, mat: Material, tangent=True):
    """First Piola-Kirchhoff stress P (ne,3,3) and A = dP/dF (ne,3,3,3,3), indices A[e,i,J,k,L]."""
    J = np.linalg.det(F)
    Finv = np.linalg.inv(F)  # Finv[e, J, i]
    H = np.transpose(Finv, (0, 2, 1))  # F^-T
    lnJ = np.log(J)
    mu, lam, c2 = mat.mu[:, None, None], mat.lam[:, None, None], mat.c2
    P = mu * (F - H) + lam * lnJ[:, None, None] * H
    A = None
    if tangent:
        eye = np.eye(3)
        A = mat.mu[:, None, None, None, None] * np.einsum("ik,JL->iJkL", eye, eye)[None]
        # d(F^-T)_iJ / dF_kL = -Finv_Jk Finv_Li
        dH = -np.einsum("eJk,eLi->eiJkL", Finv, Finv)
        A = A - (mat.mu - mat.lam * lnJ)[:, None, None, None, None] * dH
        A = A + mat.lam[:, None, None, None, None] * np.einsum("eiJ,ekL->eiJkL", H, H)
    if c2.any():
        I1 = np.einsum("eij,eij->e", F, F)
        a = J ** (-2.0 / 3.0)
        Ib = a * I1
        G = a[:, None, None] * (2 * F - (2.0 / 3.0) * I1[:, None, None] * H)
        s = (2 * c2 * (Ib - 3))[:, None, None]
        P = P + s * G
        if tangent:
            eye = np.eye(3)
            dG = -(2.0 / 3.0) * np.einsum("eiJ,ekL->eiJkL", G, H)
            dG = dG + a[:, None, None, None, None] * (
                2 * np.einsum("ik,JL->iJkL", eye, eye)[None]
                - (4.0 / 3.0) * np.einsum("ekL,eiJ->eiJkL", F, H)
                - (2.0 / 3.0) * I1[:, None, None, None, None] * dH
            )
            A = A + (2 * c2)[:, None, None, None, None] * (
                np.einsum("eiJ,ekL->eiJkL", G, G) + (Ib - 3)[:, None, None, None, None] * dG
            )
    return P, A


class Body:
    """A meshed body: nodes X (n,3), tets T (ne,4); material per element."""

    def __init__(self, X, T, mat: Material):
        self.X = np.asarray(X, float)
        self.T, self.V, self.B = tet_geometry(self.X, np.asarray(T))
        self.mat = mat
        self.n = len(self.X)
        ne = len(self.T)
        # sparse pattern: dof index of (a,i)
        dof = (3 * self.T[:, :, None] + np.arange(3)[None, None, :]).reshape(ne, 12)
        self._rows = np.repeat(dof, 12, axis=1).ravel()
        self._cols = np.tile(dof, (1, 12)).ravel()
        self._dof = dof

    def F(self, u):
        x = self.X + u.reshape(-1, 3)
        return np.einsum("eai,eaJ->eiJ", x[self.T], self.B)

    def internal(self, u, tangent=True):
        F = self.F(u)
        if (np.linalg.det(F) <= 0).any():
            raise SolveError("inverted element")
        P, A = stress_tangent(F, self.mat, tangent)
        fe = self.V[:, None, None] * np.einsum("eiJ,eaJ->eai", P, self.B)  # (ne,4,3)
        f = np.zeros(3 * self.n)
        np.add.at(f, self._dof.ravel(), fe.reshape(-1))
        K = None
        if tangent:
            Ke = self.V[:, None, None, None, None] * np.einsum("eaJ,eiJkL,ebL->eaibk", self.B, A, self.B)
            Ke = Ke.reshape(len(self.T), 12, 12)
            K = sp.csr_matrix((Ke.ravel(), (self._rows, self._cols)), shape=(3 * self.n, 3 * self.n))
        return f, K

    def strain_energy(self, u):
        W = energy_density(self.F(u), self.mat)
        if W is None:
            return np.inf
        return float(self.V @ W)


def factor(K):
    """Sparse direct factorisation of a symmetric matrix (SuperLU, minimum degree on K + K^T,
    symmetric mode with diagonal pivots); returns the solve function."""
    lu = spla.splu(sp.csc_matrix(K), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                   options=dict(SymmetricMode=True))
    return lu.solve


class Problem:
    """Body + fixed dofs + linear springs to ground (per dof) + dead external force vector."""

    def __init__(self, body: Body, fixed_nodes=(), spring=None, fixed_dofs=None):
        self.body = body
        fixed = np.zeros(3 * body.n, bool)
        fn = np.asarray(list(fixed_nodes), int)
        if len(fn):
            fixed[(3 * fn[:, None] + np.arange(3)).ravel()] = True
        if fixed_dofs is not None:
            fixed |= np.asarray(fixed_dofs, bool)
        self.free = np.flatnonzero(~fixed)
        self.spring = np.zeros(3 * body.n) if spring is None else np.asarray(spring, float)

    def potential(self, u, fext):
        e = self.body.strain_energy(u)
        return e + 0.5 * float(self.spring @ (u * u)) - float(fext @ u)

    def residual(self, u, fext, tangent=True):
        fi, K = self.body.internal(u, tangent)
        r = fi + self.spring * u - fext
        if tangent:
            K = K + sp.diags(self.spring)
        return r, K

    def newton(self, u0, fext, tol=1e-9, max_iter=40):
        """Equilibrium from u0 under fext. Returns (u, iterations). Raises SolveError."""
        u = u0.copy()
        free = self.free
        scale = max(np.linalg.norm(fext[free]), 1e-12)
        Pi = self.potential(u, fext)
        for it in range(1, max_iter + 1):
            r, K = self.residual(u, fext)
            rn = np.linalg.norm(r[free])
            if rn <= tol * scale:
                return u, it - 1
            try:
                du_f = factor(K[free][:, free])(-r[free])
            except RuntimeError as e:  # singular
                raise SolveError(f"singular tangent: {e}")
            du = np.zeros_like(u)
            du[free] = du_f
            # backtracking line search on the potential (Armijo), rejecting inverted states
            slope = float(r[free] @ du_f)  # dPi/dalpha at 0 (< 0 for a descent direction)
            tiny = abs(slope) <= 1e-11 * max(abs(Pi), 1e-30)  # energy change below round-off
            alpha = 1.0
            for _ in range(40):
                un = u + alpha * du
                Pn = self.potential(un, fext)
                if np.isfinite(Pn) and (tiny or Pn <= Pi + 1e-4 * alpha * min(slope, 0.0)):
                    break
                alpha *= 0.5
            else:
                raise SolveError("line search failed")
            u, Pi = un, Pn
            if np.linalg.norm(alpha * du_f) <= 1e-12 * max(1e-3, np.abs(u).max()):
                r, _ = self.residual(u, fext, tangent=False)
                if np.linalg.norm(r[free]) <= 1e-6 * scale:
                    return u, it
        r, _ = self.residual(u, fext, tangent=False)
        if np.linalg.norm(r[free]) <= 1e-6 * scale:
            return u, max_iter
        raise SolveError(f"Newton did not converge in {max_iter} iterations (|r|/|f| = {np.linalg.norm(r[free]) / scale:.2e})")

    def solve(self, fext, u_start=None, f_start=None, steps=2, min_step=1.0 / 256):
        """Load stepping from (u_start under f_start) to fext in `steps` equal increments; an
        increment whose Newton fails is halved. Returns (u, total Newton iterations)."""
        u = np.zeros(3 * self.body.n) if u_start is None else u_start.copy()
        f0 = np.zeros_like(fext) if f_start is None else f_start
        t, dt, iters = 0.0, 1.0 / steps, 0
        while t < 1.0 - 1e-12:
            dt = min(dt, 1.0 - t)
            try:
                u_new, k = self.newton(u, f0 + (t + dt) * (fext - f0))
            except SolveError:
                if dt <= min_step:
                    raise
                dt *= 0.5
                continue
            u, t, iters = u_new, t + dt, iters + k
            dt = min(2 * dt, 1.0 / steps)
        return u, iters
