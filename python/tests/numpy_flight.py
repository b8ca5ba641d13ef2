"""The flight model of docs/models.md ("Flight", "Reynolds number") written in numpy, and its RK4:
an independent check of `ttball.predict` and the reference of the benchmark (bench.py).

    dv/dt = -g e_z - k_D C_D(Re, Sp) rho S_b / m |v| v + k_M C_M(Re, Sp) rho V_b / m (w x v)
    dw/dt = -lambda w
    C_D = P_D(Sp) f(Re)^a_D,  C_M = P_M(Sp) f(Re)^a_M,  Sp = r |w x v| / |v|^2 (to Sp_max)
    f(Re) = [(1 + (Re / Re_0)^4) / (1 + (Re / Re_max)^4)]^(1/4),  Re = 2 r |v| / nu

Free flight only: no table, net or floor.
"""

import math

import numpy as np
import yaml


class Flight:
    """The model's constants from a `ttball.Config`."""

    def __init__(self, config):
        p = yaml.safe_load(config.yaml())["ttball"]["ros__parameters"]
        r, m, rho = p["ball"]["radius"], p["ball"]["mass"], p["air"]["density"]
        aero = p["aero"]
        self.g = p["gravity"]
        self.r = r
        self.drag = aero["drag_scale"] * rho * 0.5 * math.pi * r * r / m
        self.magnus = aero["magnus_scale"] * rho * 4.0 / 3.0 * math.pi * r**3 / m
        # numpy's polyval takes the highest order first.
        self.p_drag = np.array(aero["drag_coefficients"][::-1])
        self.p_magnus = np.array(aero["magnus_coefficients"][::-1])
        self.sp_max = aero["spin_parameter_max"]
        self.re_per_speed = 2.0 * r / p["air"]["kinematic_viscosity"]
        self.re_range = aero["reynolds_range"]
        self.a_drag, self.a_magnus = aero["reynolds_exponents"]
        self.decay = aero["spin_decay_rate"]

    def derivative(self, x):
        v, w = x[3:6], x[6:9]
        speed = np.linalg.norm(v)
        c = np.cross(w, v)
        sp = min(self.r * np.linalg.norm(c) / speed**2, self.sp_max) if speed > 0 else 0.0
        re = self.re_per_speed * speed
        f = ((1 + (re / self.re_range[0]) ** 4) / (1 + (re / self.re_range[1]) ** 4)) ** 0.25
        cd = np.polyval(self.p_drag, sp) * f**self.a_drag
        cm = np.polyval(self.p_magnus, sp) * f**self.a_magnus
        a = -self.drag * cd * speed * v + self.magnus * cm * c
        a[2] -= self.g
        return np.concatenate([v, a, -self.decay * w])

    def rk4(self, x, duration, step):
        """The states every `step` seconds from `x` over `duration`, by RK4."""
        n = int(round(duration / step))
        states = np.empty((n + 1, 9))
        states[0] = x
        for k in range(n):
            s = states[k]
            k1 = self.derivative(s)
            k2 = self.derivative(s + 0.5 * step * k1)
            k3 = self.derivative(s + 0.5 * step * k2)
            k4 = self.derivative(s + step * k3)
            states[k + 1] = s + step / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        return states
