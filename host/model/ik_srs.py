"""The closed form for an S-R-S arm (IKAN: Tolani, Goswami, Badler, Graphical Models 2000): finding
the shoulder-elbow-wrist structure in a chain, the three-angle split of a rotation about any axes,
the branches at each swivel and the search for the in-limit swivel nearest the preferred one.
Mixed into `ik.Arm`; the method is described in ik's docstring."""

from __future__ import annotations

import math

import numpy as np

from .ik_chain import NoSwivel, OutOfReach, _cross, _Srs
from .rotations import axis_angle, skew, turn

TOL_LIMIT = 1e-10      # rad: a solution this far past a limit is clipped onto it (changes the hand < 1e-10 m)
TOL_REACH = 1e-12      # relative: the law of cosines accepts rounding this far past full reach
STRUCTURE_TOL = 1e-9   # m: axes meeting within this distance meet
GRID = 72              # swivels tried at once when the preferred one is outside the limits (5° apart)


def _euler(G, w0, w1, w2, hint0):
    """Both branches of G = Rot(w0, a) Rot(w1, b) Rot(w2, c) for any axes with w1 across w0 and w2:
    angles (N, 2, 3) for G (N, 3, 3). In gimbal lock (a and c turn about one line) a = hint0."""
    K0, K1 = skew(w0), skew(w1)
    w12 = K1 @ w2
    c1 = w0 @ w2 - (w0 @ w1) * (w1 @ w2)
    s1 = w0 @ w12
    k = (w0 @ w1) * (w1 @ w2)
    Gw2 = G @ w2
    value = Gw2 @ w0
    alpha = math.atan2(s1, c1)
    # cos(b - alpha) = (value - k) / rho; its sine from |w0 x G w2|, exact near the lock too
    across = np.sum((Gw2 @ K0.T) ** 2, axis=-1) + 2 * value * k - (w0 @ w1) ** 2 - (w1 @ w2) ** 2
    spread = np.arctan2(np.sqrt(np.maximum(across, 0.0)), value - k)
    b = np.stack([alpha + spread, alpha - spread], axis=1)              # (N, 2)
    cb, sb = np.cos(b)[..., None], np.sin(b)[..., None]
    v = w2 * cb + w12 * sb + w1 * ((w1 @ w2) * (1 - cb))                # Rot(w1, b) w2, (N, 2, 3)
    # a: the turn about w0 taking v to G w2
    ap = v - (v @ w0)[..., None] * w0
    bp = (Gw2 - value[:, None] * w0)[:, None, :]
    a = np.arctan2(np.sum((ap @ K0.T) * bp, axis=-1), np.sum(ap * bp, axis=-1))
    a = np.where(np.sum(ap * ap, axis=-1) < 1e-18, hint0, a)
    # c: what Rot(w1, -b) Rot(w0, -a) G does to a vector x across w2
    x = _cross(w2, w0 if abs(w0 @ w2) < 0.9 else w1)
    x /= np.linalg.norm(x)
    y = turn(w1, -b, turn(w0, -a, (G @ x)[:, None, :]))
    c = np.arctan2(y @ (skew(w2) @ x), y @ x)
    return np.stack([a, b, c], axis=-1)


class ClosedForm:
    """The S-R-S methods of `ik.Arm` (on a `ik_chain.Chain`)."""

    # ---------------------------------------------------------------- S-R-S structure
    def _find_srs(self) -> tuple[_Srs | None, str]:
        if self.n < 7:
            return None, f"{self.n} dofs to the hand, an S-R-S arm has 7"
        w, r = self.axis[-7:], self.point[-7:]

        def meet(ks):
            A = sum(np.eye(3) - np.outer(w[k], w[k]) for k in ks)
            c = np.linalg.lstsq(A, sum((np.eye(3) - np.outer(w[k], w[k])) @ r[k] for k in ks), rcond=None)[0]
            gap = max(np.linalg.norm(_cross(w[k], c - r[k])) for k in ks)
            return c, gap

        S, gap_s = meet((0, 1, 2))
        W, gap_w = meet((4, 5, 6))
        if gap_s > STRUCTURE_TOL:
            return None, f"the first three of the last seven axes miss one point by {gap_s:.2g} m"
        if gap_w > STRUCTURE_TOL:
            return None, f"the last three axes miss one point by {gap_w:.2g} m"
        if np.linalg.norm(W - self.end_p) > STRUCTURE_TOL:
            return None, "the hand's origin is not where the wrist axes meet"
        for k0, k1, k2, what in ((0, 1, 2, "shoulder"), (4, 5, 6, "wrist")):
            if min(np.linalg.norm(_cross(w[k0], w[k1])), np.linalg.norm(_cross(w[k1], w[k2]))) < 0.1:
                return None, f"the {what}'s middle axis runs nearly along another"
        we, re = w[3], r[3]
        u = (W - re) - we * (we @ (W - re))
        v = (S - re) - we * (we @ (S - re))
        if min(np.linalg.norm(u), np.linalg.norm(v)) < 1e-6:
            return None, "the elbow axis passes through the shoulder or the wrist"
        # reach over the elbow's range: |W(θ) - S| at the ends and where it is longest or shortest
        lo, hi = self.lower[-4], self.upper[-4]
        theta = np.linspace(max(lo, -math.pi), min(hi, math.pi), 2001)
        d = np.linalg.norm(turn(we, theta, np.broadcast_to(W - re, (len(theta), 3))) + re - S, axis=1)
        return _Srs(S=S, W=W, min_reach=float(d.min()), max_reach=float(d.max()),
                    elbow_lo=lo, elbow_hi=hi), ""


    def _candidates(self, pos, rot, phi, x_prev):
        """Every branch at each swivel: angles (N, C, 7) of the S-R-S dofs (C ≤ 8)."""
        s, w, r = self.srs, self.axis[-7:], self.point[-7:]
        n_vec, d = pos - s.S, np.linalg.norm(pos - s.S)
        n_hat = n_vec / d
        # elbow: the law of cosines (Paden-Kahan subproblem 3 about the elbow axis)
        we, re = w[3], r[3]
        u, v = s.W - re, s.S - re
        up, vp = u - we * (we @ u), v - we * (we @ v)
        # the angle between u' and v' whose opposite side is the target's distance across the axis,
        # by half-angle tangents (exact at full stretch, where an arccos loses half the digits)
        a, b = np.linalg.norm(up), np.linalg.norm(vp)
        delta = math.sqrt(max(d * d - (we @ (u - v)) ** 2, 0.0))
        opposite = math.sqrt(max((delta - (a - b)) * (delta + (a - b)), 0.0))
        adjacent = math.sqrt(max((a + b - delta) * (a + b + delta), 0.0))
        spread = 2 * math.atan2(opposite, adjacent)
        theta0 = math.atan2(we @ _cross(up, vp), up @ vp)
        elbows = {theta0 + spread, theta0 - spread}
        # the swivel's reference: down (-z) across the shoulder-wrist line, or back (-x) along it
        ref = np.array([0.0, 0.0, -1.0]) - n_hat * -n_hat[2]
        if np.linalg.norm(ref) < 1e-9:
            ref = np.array([-1.0, 0.0, 0.0]) - n_hat * -n_hat[0]
        ref /= np.linalg.norm(ref)
        # elbow angles outside the elbow's limits are no branch (unless both are: then the least bad)
        elbows = sorted(elbows)
        lo, hi = self.lower[-4], self.upper[-4]
        wrapped = [t + 2 * math.pi * round(((lo + hi) / 2 - t) / (2 * math.pi)) if math.isfinite(lo + hi) else t
                   for t in elbows]
        inside = [t for t, tw in zip(elbows, wrapped) if lo - TOL_LIMIT <= tw <= hi + TOL_LIMIT]
        elbows = inside or elbows
        phi = np.asarray(phi, dtype=float)
        N, ne = len(phi), len(elbows)
        Rs, E3s = np.empty((ne, N, 3, 3)), np.empty((ne, 3, 3))
        for e, t3 in enumerate(elbows):
            E3 = E3s[e] = axis_angle(we, t3)
            s0 = (E3 @ (s.W - re) + re) - s.S
            s0 /= np.linalg.norm(s0)
            # the smallest rotation taking s0 onto n, then the swivel about n
            axis = _cross(s0, n_hat)
            sin_a, cos_a = np.linalg.norm(axis), float(s0 @ n_hat)
            if sin_a < 1e-12:
                axis = _cross(s0, we if abs(s0 @ we) < 0.9 else w[0])
                sin_a = 0.0
            R_min = axis_angle(axis, math.atan2(sin_a, cos_a))
            bend = _cross(n_hat, R_min @ we)
            phi0 = math.atan2(_cross(ref, bend) @ n_hat, ref @ bend)
            Rs[e] = axis_angle(n_hat, phi - phi0) @ R_min
        Rs = Rs.reshape(ne * N, 3, 3)
        shoulder = _euler(Rs, w[0], w[1], w[2], x_prev[0])                  # (ne N, 2, 3)
        if rot is not None:
            E3n = np.repeat(E3s, N, axis=0)
            Rw = np.swapaxes(Rs @ E3n, 1, 2) @ (rot @ self.end_R.T)           # E3ᵀ Rsᵀ R end_Rᵀ
            wrist = _euler(Rw, w[4], w[5], w[6], x_prev[4])                 # (ne N, 2, 3)
        else:
            wrist = np.broadcast_to(x_prev[4:7], (ne * N, 1, 3))
        ns, nw = shoulder.shape[1], wrist.shape[1]
        c = np.empty((ne, N, ns, nw, 7))
        c[..., 0:3] = shoulder.reshape(ne, N, ns, 1, 3)
        c[..., 3] = np.array(elbows)[:, None, None, None]
        c[..., 4:7] = wrist.reshape(ne, N, 1, nw, 3)
        return c.transpose(1, 0, 2, 3, 4).reshape(N, ne * ns * nw, 7)

    def _fit(self, cand, x_prev):
        """Wrap each angle to the turn nearest its range (or x_prev); the largest limit excess."""
        lo, hi = self.lower[-7:], self.upper[-7:]
        mid = np.where(np.isfinite(lo) & np.isfinite(hi), (lo + hi) / 2, x_prev)
        cand = cand + 2 * math.pi * np.round((mid - cand) / (2 * math.pi))
        excess = np.maximum(np.maximum(lo - cand, cand - hi), 0.0).max(axis=-1)
        return cand, excess

    def _pick(self, pos, rot, phi, x_prev, x_ref):
        """The in-limit branch nearest x_ref at each swivel: (angles (N, 7), excess (N,))."""
        cand, excess = self._fit(self._candidates(pos, rot, phi, x_prev), x_prev)
        cost = np.sum((cand - x_ref) ** 2, axis=-1) + 1e6 * np.maximum(excess - TOL_LIMIT, 0.0)
        best = np.argmin(cost, axis=1)
        rows = np.arange(len(phi))
        return cand[rows, best], excess[rows, best]

    def swivel_of(self, x) -> float:
        """The swivel (rad) of the S-R-S arm at chain angles x."""
        R, p, axes, pivots = self.forward(x)
        Rp, pp = self._prefix(x)
        S = Rp @ self.srs.S + pp
        return self._swivel_at(Rp.T @ (p - S), Rp.T @ axes[-4])

    def _swivel_at(self, n_vec, elbow_axis) -> float:
        n_hat = n_vec / np.linalg.norm(n_vec)
        ref = np.array([0.0, 0.0, -1.0]) - n_hat * -n_hat[2]
        if np.linalg.norm(ref) < 1e-9:
            ref = np.array([-1.0, 0.0, 0.0]) - n_hat * -n_hat[0]
        ref /= np.linalg.norm(ref)
        bend = _cross(n_hat, elbow_axis)
        return math.atan2(_cross(ref, bend) @ n_hat, ref @ bend)

    def solve_srs(self, x_prev, pos, rot, swivel, cold):
        """Closed form; (x, swivel) or an IkError."""
        s = self.srs
        Rp, pp = self._prefix(x_prev)
        pos_l = Rp.T @ (pos - pp)
        rot_l = None if rot is None else Rp.T @ rot
        d = float(np.linalg.norm(pos_l - s.S))
        if d > s.max_reach * (1 + TOL_REACH) or d < s.min_reach * (1 - TOL_REACH):
            far = d > s.max_reach
            raise OutOfReach(f"out of reach: the target is {d:.3f} m from the shoulder, the arm reaches "
                             + (f"{s.max_reach:.3f} m" if far else
                                f"no nearer than {s.min_reach:.3f} m within the elbow's limits"))
        tail = x_prev[-7:]
        x_ref = tail if not cold else np.clip(np.zeros(7), self.lower[-7:], self.upper[-7:])
        if swivel is not None:
            phis = np.array([float(swivel)])
        else:
            if cold:
                preferred = 0.0
            else:
                # keep the elbow's previous bending direction, as seen across the new line
                preferred = self._swivel_at(pos_l - s.S, Rp.T @ self._elbow_axis(x_prev))
            phis = np.array([preferred])
        if cold and swivel is None:
            return self._search_swivel(pos_l, rot_l, float(phis[0]), tail, x_ref)
        x, excess = self._pick(pos_l, rot_l, phis, tail, x_ref)
        if excess[0] <= TOL_LIMIT:
            return x[0], float(phis[0])
        if swivel is not None:
            raise NoSwivel(f"no solution inside the limits at swivel {math.degrees(swivel):.1f}°")
        return self._search_swivel(pos_l, rot_l, float(phis[0]), tail, x_ref)

    def _search_swivel(self, pos, rot, preferred, x_prev, x_ref):
        """The in-limit swivel nearest `preferred`: a grid round the circle, then finer grids
        between the nearest in-limit swivel and the preferred one (or round the least excess)."""
        phis = preferred + np.linspace(0.0, 2 * math.pi, GRID, endpoint=False)
        x, excess = self._pick(pos, rot, phis, x_prev, x_ref)
        ok = excess <= TOL_LIMIT
        if ok[0]:
            return x[0], preferred
        if not ok.any():
            # none inside: look closer round the three least bad swivels
            for k in np.argsort(excess)[:3]:
                for width in (2 * math.pi / GRID, 2 * math.pi / GRID / 16):
                    fine = phis[k] + np.linspace(-width, width, 33)
                    xf, ef = self._pick(pos, rot, fine, x_prev, x_ref)
                    k_best = int(np.argmin(ef))
                    phis[k], excess[k], x[k] = fine[k_best], ef[k_best], xf[k_best]
                    if ef[k_best] <= TOL_LIMIT:
                        return xf[k_best], float(fine[k_best])
            raise NoSwivel("no swivel inside the limits: every elbow position about the shoulder-wrist line "
                           "puts a joint past its limit")
        signed = np.angle(np.exp(1j * (phis - preferred)))
        k = int(np.argmin(np.where(ok, np.abs(signed), np.inf)))
        # close in on the edge of the in-limit range from the preferred swivel's side, between the
        # in-limit grid swivel and its neighbour towards the preferred one (to 1/16 of a step, 0.3°)
        step = 2 * math.pi / GRID
        far = preferred + signed[k]
        fine = np.linspace(far - math.copysign(step, signed[k]), far, 17)
        xf, ef = self._pick(pos, rot, fine, x_prev, x_ref)
        inside = np.flatnonzero(ef <= TOL_LIMIT)
        if not len(inside):                                   # (the last is the grid's swivel: inside)
            return x[k], float(phis[k])
        return xf[inside[0]], float(fine[inside[0]])
