"""An independent model of one segment on its three actuators, written from the documented
equations in actuator coordinates (no modal decomposition), with the servo as explicit
difference equations. The tests compare the FMUs against it.

State per actuator k: node position/velocity, mirror position/velocity at the actuator point,
shunt coordinate/rate, whiffletree position/velocity. The glass is a rigid body (mass
m - m_w, inertia I - m_w r^2 / 2) whose displacement at the actuators is z = P q,
q = (piston, slope_x, slope_y); its actuator-space mass matrix is P^-T diag(m, I, I) P^-1. The
whiffletree is a third of m_w at each actuator point, on a spring k_w to its node. The glass's
flexures act on piston and tilt patterns with the stiffness set by their modes with the
whiffletree clamped: K_s = k_p Pi + k_t (I - Pi), Pi = 1 1^T / 3. k_w is found here by bisection
on the lowest eigenvalue of the clamped-node tilt chain (the documented definition of
whiffletree_frequency), not from the closed form the Rust code uses.
"""
import numpy as np
from scipy.linalg import eigvals, expm


class SegmentReference:
    def __init__(self, p, piezo):
        self.p = p
        self.piezo = piezo
        m, inertia, r = p["segment_mass"], p["segment_inertia"], p["actuator_radius"]
        mw = p["support_mass"]
        mglass, iglass = m - mw, inertia - mw * r * r / 2
        th = 2 * np.pi * np.arange(3) / 3
        P = np.column_stack([np.ones(3), r * np.cos(th), r * np.sin(th)])
        Pinv = np.linalg.inv(P)
        self.Mg = Pinv.T @ np.diag([mglass, iglass, iglass]) @ Pinv
        self.mw = mw / 3
        Pi = np.ones((3, 3)) / 3
        m_p = mglass / 3
        m_t = iglass / (1.5 * r * r)
        k_p = m_p * (2 * np.pi * p["support_piston_frequency"]) ** 2
        k_t = m_t * (2 * np.pi * p["support_tilt_frequency"]) ** 2
        z = p["support_damping_ratio"]
        c_p, c_t = 2 * z * np.sqrt(k_p * m_p), 2 * z * np.sqrt(k_t * m_t)
        self.Ks = k_p * Pi + k_t * (np.eye(3) - Pi)
        self.Cs = c_p * Pi + c_t * (np.eye(3) - Pi)
        self.k_p, self.k_t = k_p, k_t
        self.k_w = self._whiffletree_stiffness(m_t, k_t, 2 * np.pi * p["whiffletree_frequency"])
        self.c_w = 2 * z * np.sqrt(self.k_w * (self.mw + m_t))
        self.ts = 1.0 / p["servo_rate"]
        self._discretise()

    def _whiffletree_stiffness(self, m_t, k_t, w):
        """k_w whose clamped-node tilt chain (k_w, m_w/3, k_t, m_t) has its lowest mode at w."""
        def lowest(kw):
            M = np.diag([self.mw, m_t])
            K = np.array([[kw + k_t, -k_t], [-k_t, k_t]])
            return np.sqrt(np.min(eigvals(K, M).real))
        lo, hi = 1.0, 1e12
        for _ in range(200):
            mid = np.sqrt(lo * hi)
            lo, hi = (mid, hi) if lowest(mid) < w else (lo, mid)
        return np.sqrt(lo * hi)

    def _continuous(self):
        p, I3, Z3 = self.p, np.eye(3), np.zeros((3, 3))
        ma = p["actuator_mass"]
        Mg_inv = np.linalg.inv(self.Mg)
        # x = [xa, va, xg, vg, e, ed, xw, vw]; w = [u, zc, fw]
        n = 24
        A = np.zeros((n, n))
        B = np.zeros((n, 9))
        xa, va, xg, vg, e, ed, xw, vw = (slice(3 * i, 3 * i + 3) for i in range(8))
        u, zc, fw = (slice(3 * i, 3 * i + 3) for i in range(3))
        A[xa, va] = I3
        A[xg, vg] = I3
        A[xw, vw] = I3
        # whiffletree spring between node and whiffletree
        kw, cw, mw = self.k_w, self.c_w, self.mw
        A[va, xa] += -kw / ma * I3
        A[va, xw] += kw / ma * I3
        A[va, va] += -cw / ma * I3
        A[va, vw] += cw / ma * I3
        A[vw, xa] += kw / mw * I3
        A[vw, xw] += -kw / mw * I3
        A[vw, va] += cw / mw * I3
        A[vw, vw] += -cw / mw * I3
        # the glass's flexures between whiffletree and glass
        A[vw, xw] += -self.Ks / mw
        A[vw, xg] += self.Ks / mw
        A[vw, vw] += -self.Cs / mw
        A[vw, vg] += self.Cs / mw
        A[vg, xw] += Mg_inv @ self.Ks
        A[vg, xg] += -Mg_inv @ self.Ks
        A[vg, vw] += Mg_inv @ self.Cs
        A[vg, vg] += -Mg_inv @ self.Cs
        B[vg, fw] = Mg_inv
        if not self.piezo:
            k, c = p["spring_stiffness"], p["spring_damping"]
            A[va, xa] += -k / ma * I3
            A[va, va] += -c / ma * I3
            B[va, zc] += k / ma * I3
            B[va, u] += 1 / ma * I3
        else:
            kd = p["piezo_stiffness"]
            c = 2 * p["piezo_damping_ratio"] * np.sqrt(kd * (ma + p["segment_mass"] / 3))
            A[va, xa] += -kd / ma * I3
            A[va, va] += -c / ma * I3
            B[va, zc] += kd / ma * I3
            B[va, u] += kd / ma * I3
            if p.get("shunt_enabled", False):
                A[va, e] += kd / ma * I3
                we = 2 * np.pi * p["shunt_frequency"]
                g = p["shunt_coupling"] ** 2 * we * we
                A[e, ed] = I3
                A[ed, e] = -we * we * I3
                A[ed, ed] = -2 * p["shunt_damping_ratio"] * we * I3
                A[ed, xa] = g * I3
                B[ed, zc] = -g * I3
                B[ed, u] = -g * I3
        return A, B

    def _discretise(self):
        A, B = self._continuous()
        n, m = B.shape
        M = np.zeros((n + m, n + m))
        M[:n, :n] = A
        M[:n, n:] = B
        E = expm(M * self.ts)
        self.Ad, self.Bd = E[:n, :n], E[:n, n:]

    def simulate(self, ticks, u_cmd, z_cell, f_wind, every=1):
        """Held inputs (3 each); returns mirror displacement (3) every `every` ticks, from t=0."""
        p = self.p
        ts = self.ts
        ai = np.exp(-2 * np.pi * p["integrator_leak"] * ts)
        ad = np.exp(-2 * np.pi * p["derivative_cutoff"] * ts)
        kp, ki, kd = p["servo_kp"], p["servo_ki"], p["servo_kd"]
        x = np.zeros(24)
        integ = np.zeros(3)
        deriv = np.zeros(3)
        prev = np.zeros(3)
        zc, fw, uc = (np.asarray(v, float) for v in (z_cell, f_wind, u_cmd))
        out = [x[6:9].copy()]
        for k in range(ticks):
            stroke = x[0:3] - zc
            err = uc - stroke
            integ = ai * integ + ts * err
            deriv = ad * deriv - (1 - ad) / ts * (stroke - prev)
            prev = stroke
            drive = (p["servo_feedforward"] * uc + kp * (p["setpoint_weight"] * uc - stroke)
                     + ki * integ + kd * deriv)
            x = self.Ad @ x + self.Bd @ np.concatenate([drive, zc, fw])
            if (k + 1) % every == 0:
                out.append(x[6:9].copy())
        return np.array(out)

    def static_stiffness_piston(self):
        """Per-actuator static stiffness at the mirror for a piston load (N/m)."""
        p = self.p
        ts = self.ts
        ai = np.exp(-2 * np.pi * p["integrator_leak"] * ts)
        if p["servo_ki"] > 0 and ai == 1.0:
            c0 = np.inf
        else:
            c0 = p["servo_kp"] + p["servo_ki"] * ts / (1 - ai)
        if self.piezo:
            k2 = p["shunt_coupling"] ** 2 if p.get("shunt_enabled", False) else 0.0
            ka = p["piezo_stiffness"] * (1 - k2) * (1 + c0)
        else:
            ka = p["spring_stiffness"] + c0
        return 1.0 / (1.0 / self.k_p + 1.0 / self.k_w + 1.0 / ka)
