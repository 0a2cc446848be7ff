#!/usr/bin/env python3
"""Independent validation-data generator "fourth-apart" (walls that do not break sharply).

VALIDATION ONLY.  Never use these files or numbers to tune, fit, calibrate or pick
thresholds of the analysis.  Written from the physics in the brief only, without reading
the analysis, its simulator, scripts, book or the other generators.

Usage: python3 validation/fourth-apart/generate.py OUT_DIR [--seed N] [--trials 10]

Python 3 standard library only.  See README.md next to this file.
"""
import argparse
import json
import math
import os
import random
import sys
import time

MM = 1e-3
HOLD_S = 5.0          # idw hold
DV2 = 5e-6            # half width of the Karnopp zero-velocity band, m/s
TIP_LEN = 0.2 * MM    # tip compression length over which the cutting force is (un)loaded


def clip(v, lo, hi):
    return lo if v < lo else hi if v > hi else v


def tgauss(rng, mu, sd, lo, hi):
    return clip(rng.gauss(mu, sd), lo, hi)


# --------------------------------------------------------------------------------------
# Relaxation kernels  G(t) = g_inf + sum_k w_k exp(-t/tau_k),  G(0) = 1
# --------------------------------------------------------------------------------------
class Kernel:
    def __init__(self, name, g_inf, nodes, params):
        self.name = name
        self.g_inf = g_inf
        self.nodes = nodes  # list of (w, tau)
        self.params = params

    def G(self, t):
        s = self.g_inf
        for w, tau in self.nodes:
            s += w * math.exp(-t / tau)
        return s

    def describe(self):
        d = dict(self.params)
        d["kind"] = self.name
        d["G_at_5s"] = round(self.G(5.0), 5)
        return d


NO_KERNEL = Kernel("none", 1.0, [], {})


def prony_kernel(rng, nbranch):
    r = rng.uniform(0.34, 0.41)  # fall of a held force over the 5 s hold
    if nbranch == 1:
        tau = rng.uniform(1.3, 1.8)
        w = r / (1.0 - math.exp(-HOLD_S / tau))
        nodes = [(w, tau)]
    else:
        t1 = rng.uniform(0.4, 0.9)
        t2 = rng.uniform(1.8, 3.5)
        a = rng.uniform(0.3, 0.6)
        nodes = [(a * r / (1.0 - math.exp(-HOLD_S / t1)), t1),
                 ((1 - a) * r / (1.0 - math.exp(-HOLD_S / t2)), t2)]
    g_inf = 1.0 - sum(w for w, _ in nodes)
    return Kernel("prony", g_inf, nodes,
                  {"branches": [{"g": round(w, 5), "tau_s": round(t, 4)} for w, t in nodes],
                   "g_inf": round(g_inf, 5), "target_hold_fall": round(r, 4)})


def qlv_kernel(rng, m=16):
    """Fung QLV reduced relaxation function with a box (continuous) spectrum between tau1, tau2:
    G(t) = [1 + C (E1(t/tau2) - E1(t/tau1))] / [1 + C ln(tau2/tau1)],
    E1 difference = int_{tau1}^{tau2} exp(-t/tau) dln(tau), evaluated by m-point midpoint rule in ln tau."""
    r = rng.uniform(0.34, 0.41)
    t1 = rng.uniform(0.05, 0.2)
    t2 = rng.uniform(2.5, 5.0)
    L = math.log(t2 / t1)
    d = L / m
    taus = [math.exp(math.log(t1) + (k + 0.5) * d) for k in range(m)]
    dE = sum(math.exp(-HOLD_S / t) for t in taus) * d
    C = r / ((1 - r) * L - dE)
    g_inf = 1.0 / (1.0 + C * L)
    nodes = [(C * d / (1.0 + C * L), t) for t in taus]
    return Kernel("fung_qlv_box", g_inf, nodes,
                  {"C": round(C, 5), "tau1_s": round(t1, 4), "tau2_s": round(t2, 4),
                   "quadrature_nodes": m, "target_hold_fall": round(r, 4)})


def power_kernel(rng, m=28):
    """G(t) = g_inf + (1-g_inf)(1 + t/t0)^-n, the power law written as a gamma-distributed
    spectrum of rates (exact identity) and evaluated with an m-node log-spaced quadrature."""
    r = rng.uniform(0.34, 0.41)
    t0 = rng.uniform(0.3, 1.0)
    n = rng.uniform(0.6, 1.2)
    lo, hi = math.log(1e-3), math.log(40.0)
    d = (hi - lo) / m
    ss = [math.exp(lo + (k + 0.5) * d) for k in range(m)]
    q = [s ** n * math.exp(-s) * d for s in ss]   # s^(n-1) e^-s * s * dln s
    tot = sum(q)
    q = [v / tot for v in q]
    psi5 = sum(qk * math.exp(-HOLD_S * s / t0) for qk, s in zip(q, ss))
    A = min(0.97, r / (1.0 - psi5))
    nodes = [(A * qk, t0 / s) for qk, s in zip(q, ss)]
    return Kernel("power_law", 1.0 - A, nodes,
                  {"t0_s": round(t0, 4), "n": round(n, 4), "relaxing_fraction": round(A, 5),
                   "g_inf": round(1 - A, 5), "quadrature_nodes": m, "target_hold_fall": round(r, 4)})


class Hered:
    """Hereditary integral R[f](t) = int G(t-s) df(s) with f linear between samples."""

    def __init__(self, k):
        self.k = k
        self.h = [0.0] * len(k.nodes)
        self.prev = 0.0

    def step(self, f, dt):
        k = self.k
        if not k.nodes:
            self.prev = f
            return f
        df = f - self.prev
        self.prev = f
        h = self.h
        tot = k.g_inf * f
        for i, (w, tau) in enumerate(k.nodes):
            a = dt / tau
            e = math.exp(-a)
            fac = (1.0 - e) / a if a > 1e-12 else 1.0
            h[i] = e * h[i] + w * df * fac
            tot += h[i]
        return tot


# --------------------------------------------------------------------------------------
# Wall give-way laws.  Undamaged loading sigma(u) is normalised to sigma(u0) = 1 and the
# wall force is phi * R[sigma]; phi is the intact factor (1 before, 0 once through).
# factor(umax, u) -> (phi, p, through), p = failed fraction (phases shaft friction and cutting in)
# --------------------------------------------------------------------------------------
class Wall:
    def __init__(self, law, u0, beta, rng, length_range):
        self.law = law
        self.u0 = u0
        self.beta = beta
        self.p = {}
        lo, hi = length_range
        if law == "sharp":
            self.u_on = u0
            self.u_th = u0
        elif law == "weibull_damage":
            L = rng.uniform(lo, hi)
            k = rng.uniform(1.5, 3.5)
            lam = L / (math.log(100.0) ** (1.0 / k))
            self.p = {"k": k, "lambda_m": lam, "giveway_len_m": L}
            self.u_on = u0
            self.u_th = u0 + L
        elif law == "cohesive_bilinear":
            L = rng.uniform(lo, hi)
            self.p = {"giveway_len_m": L}
            self.u_on = u0
            self.u_th = u0 + L
        elif law == "cohesive_exponential":
            L = rng.uniform(lo, hi)
            self.p = {"giveway_len_m": L, "delta_m": L / 6.638}
            self.u_on = u0
            self.u_th = u0 + L
        elif law == "micro_rupture":
            L = rng.uniform(max(lo, 1.5 * MM), max(hi, 1.6 * MM))
            n = rng.randint(30, 60)
            gaps = [rng.expovariate(1.0) for _ in range(n)]
            tg = sum(gaps) + rng.expovariate(1.0) * 0.3
            pos, c = [], 0.0
            for g in gaps:
                c += g
                pos.append(u0 + L * c / tg)
            pos[-1] = u0 + L
            drops = [rng.gammavariate(4.0, 1.0) for _ in range(n)]
            td = sum(drops)
            self.rupt = list(zip(pos, [d / td for d in drops]))
            self.p = {"giveway_len_m": L, "n_ruptures": n}
            self.u_on = u0
            self.u_th = u0 + L
        elif law == "dimple_plateau_tear":
            Lp = rng.uniform(0.5 * MM, 2.0 * MM)
            Lt = rng.uniform(0.3 * MM, 1.0 * MM)
            self.P = 1.0 / 0.85
            self.p = {"plateau_len_m": Lp, "tear_len_m": Lt, "giveway_len_m": Lp + Lt}
            self.u_on = u0
            self.u_pe = u0 + Lp
            self.u_th = u0 + Lp + Lt
            self.f_pe = self._plateau(self.sigma(self.u_pe))
        elif law == "multilayer":
            shares = [rng.uniform(0.3, 0.5), rng.uniform(0.3, 0.5)]
            shares.append(max(0.1, 1.0 - sum(shares)))
            t = sum(shares)
            shares = [s / t for s in shares]
            layers, u = [], u0
            for i in range(3):
                ell = rng.uniform(0.3 * MM, 0.7 * MM)
                layers.append((u, ell, shares[i]))
                if i < 2:
                    u += rng.uniform(0.2 * MM, 0.8 * MM)
            self.layers = layers
            self.p = {"layers": [{"name": nm, "onset_m": a, "len_m": b, "share": c}
                                 for nm, (a, b, c) in zip(("adventitia", "media", "intima"), layers)]}
            self.u_on = u0
            self.u_th = layers[-1][0] + layers[-1][1]
            self.p["giveway_len_m"] = self.u_th - u0
        else:
            raise ValueError(law)
        self.sig_on = self.sigma(self.u_on)

    def sigma(self, u):
        if u <= 0:
            return 0.0
        z = u / self.u0
        return self.beta * z + (1.0 - self.beta) * z * z

    def _plateau(self, sg):
        P = self.P
        if sg <= 0.85 * P:
            return sg
        return P - 0.15 * P * math.exp(-(sg - 0.85 * P) / (0.15 * P))

    def factor(self, umax, u):
        law = self.law
        if umax >= self.u_th and law != "weibull_damage" and law != "cohesive_exponential":
            return 0.0, 1.0, True
        if law == "sharp":
            return 1.0, 0.0, False
        sg = self.sigma(u)
        if sg <= 0:
            return 1.0, 0.0, False
        if law == "weibull_damage":
            if umax <= self.u_on:
                return 1.0, 0.0, False
            phi = math.exp(-((umax - self.u_on) / self.p["lambda_m"]) ** self.p["k"])
            if phi <= 0.01:
                return 0.0, 1.0, True
            return phi, 1.0 - phi, False
        if law == "cohesive_bilinear":
            if umax <= self.u_on:
                return 1.0, 0.0, False
            s = (umax - self.u_on) / self.p["giveway_len_m"]
            return self.sig_on * (1.0 - s) / sg, s, False
        if law == "cohesive_exponential":
            if umax <= self.u_on:
                return 1.0, 0.0, False
            x = (umax - self.u_on) / self.p["delta_m"]
            g = (1.0 + x) * math.exp(-x)
            if g <= 0.01:
                return 0.0, 1.0, True
            return self.sig_on * g / sg, 1.0 - g, False
        if law == "micro_rupture":
            phi = 1.0
            for pos, d in self.rupt:
                if pos <= umax:
                    phi -= d
                else:
                    break
            phi = max(phi, 0.0)
            return phi, 1.0 - phi, False
        if law == "dimple_plateau_tear":
            if umax <= self.u_pe:
                return self._plateau(sg) / sg, 0.0, False
            s = (umax - self.u_pe) / self.p["tear_len_m"]
            g = 0.5 * (1.0 + math.cos(math.pi * s))
            return self.f_pe * g / sg, 1.0 - g, False
        if law == "multilayer":
            phi = 0.0
            for a, ell, c in self.layers:
                if umax <= a:
                    phi += c
                elif umax < a + ell:
                    phi += c * 0.5 * (1.0 + math.cos(math.pi * (umax - a) / ell))
            return phi, 1.0 - phi, False
        raise ValueError(law)

    def describe(self):
        d = {"law": self.law, "onset_u_m": round(self.u_on, 7), "through_u_m": round(self.u_th, 7),
             "linear_share_beta": round(self.beta, 4)}
        for k, v in self.p.items():
            d[k] = round(v, 7) if isinstance(v, float) else v
        if self.law == "multilayer":
            d["layers"] = [{k: (round(v, 7) if isinstance(v, float) else v) for k, v in L.items()}
                           for L in self.p["layers"]]
        return d


# --------------------------------------------------------------------------------------
# Stage motion: rests, trapezoidal moves, (1 - cos) oscillation
# --------------------------------------------------------------------------------------
class Motion:
    def __init__(self, x0):
        self.segs = []
        self.t = 0.0
        self.x = x0
        self.i = 0

    def rest(self, T):
        self.segs.append(("rest", self.t, self.t + T, self.x))
        self.t += T

    def move(self, xb, vmax, acc):
        D = abs(xb - self.x)
        sg = 1.0 if xb >= self.x else -1.0
        ta = vmax / acc
        if D >= vmax * ta:
            T = D / vmax + ta
            vpk = vmax
        else:
            ta = math.sqrt(D / acc)
            T = 2 * ta
            vpk = acc * ta
        self.segs.append(("move", self.t, self.t + T, self.x, sg, ta, T, vpk, acc, D))
        self.t += T
        self.x = xb

    def osc(self, A, f, cycles):
        T = cycles / f
        self.segs.append(("osc", self.t, self.t + T, self.x, A, 2 * math.pi * f))
        self.t += T
        self.x = self.x - A * (1.0 - math.cos(2 * math.pi * cycles))

    def eval(self, t):
        segs = self.segs
        while self.i < len(segs) - 1 and t >= segs[self.i][2]:
            self.i += 1
        s = segs[self.i]
        tau = min(max(t - s[1], 0.0), s[2] - s[1])
        if s[0] == "rest":
            return s[3], 0.0
        if s[0] == "move":
            _, _, _, x0, sg, ta, T, vpk, a, D = s
            if tau < ta:
                d, v = 0.5 * a * tau * tau, a * tau
            elif tau < T - ta:
                d, v = 0.5 * a * ta * ta + vpk * (tau - ta), vpk
            else:
                tr = T - tau
                d, v = D - 0.5 * a * tr * tr, a * tr
            return x0 + sg * d, sg * v
        _, _, _, x0, A, w = s
        return x0 - A * (1.0 - math.cos(w * tau)), -A * w * math.sin(w * tau)


def sample_times(rng, T_end, fs, jit, p_gap):
    ts, t, last = [], 0.0, -1.0
    while t <= T_end:
        tr = round(t * 1e4) / 1e4
        if tr > last:
            ts.append(tr)
            last = tr
        if p_gap > 0 and rng.random() < p_gap:
            dt = rng.uniform(0.03, 0.07)
        else:
            dt = max(0.3 / fs, (1.0 / fs) * (1.0 + jit * rng.gauss(0.0, 1.0)))
        t += dt
    return ts


# --------------------------------------------------------------------------------------
# Datasets
# --------------------------------------------------------------------------------------
DATASETS = [
    # name, protocol, tissue, first-wall laws (cycled over trials), relaxation, internal walls
    ("artery_none", "idw", "artery", ["weibull_damage"], None, False),
    ("artery_prony", "idw", "artery", ["cohesive_bilinear", "cohesive_exponential"], "prony12", False),
    ("artery_qlv", "idw", "artery", ["micro_rupture"], "qlv", False),
    ("artery_power_law", "idw", "artery", ["dimple_plateau_tear"], "power_law", False),
    ("skin_tearing", "idw", "skin", ["weibull_damage", "cohesive_exponential", "cohesive_bilinear"],
     "prony2", False),
    ("vessel_below", "idw", "liver", ["sharp"], None, True),
    ("vessel_below_relaxing", "idw", "liver", ["sharp"], "prony12", True),
    ("paper_artery_none", "paper", "artery", ["multilayer"], None, False),
    ("paper_artery_relaxing", "paper", "artery", ["micro_rupture", "cohesive_exponential"], "prony2",
     False),
]

LAW_TEXT = {
    "sharp": "paper's capsule: f = a1 u + a2 u^2 up to the puncture depth, then the capsule force vanishes "
             "between two samples",
    "weibull_damage": "continuum damage: f = (1-D) sigma(u), D = 1 - exp(-((u_max-u_on)/lambda)^k) "
                      "(Weibull), through when 1-D <= 0.01; lambda from the give-way length L = lambda (ln 100)^(1/k)",
    "cohesive_bilinear": "cohesive zone, bilinear: after onset the wall traction falls linearly from "
                         "sigma(u_on) to 0 over the separation L",
    "cohesive_exponential": "cohesive zone, exponential softening: f = sigma(u_on)(1+s/delta)exp(-s/delta), "
                            "s = u_max-u_on, through at 1 % (s = 6.64 delta = L)",
    "micro_rupture": "crack propagating in n (30-60) micro-ruptures: f = phi(u_max) sigma(u), phi drops by Gamma(4) "
                     "distributed fractions at exponential-gap positions spread over L (sawtooth: reload "
                     "between drops)",
    "dimple_plateau_tear": "wall dimples/buckles: f follows sigma until 0.85 P, then saturates smoothly to the "
                           "plateau P (C1 exponential saturation) over the plateau length, then tears with a "
                           "half-cosine over the tear length",
    "multilayer": "three layers (adventitia, media, intima) share the load sigma(u); each gives way with a "
                  "half-cosine over 0.3-0.7 mm, onsets 0.2-0.8 mm apart (three small successive give-ways)",
}

TISSUE = {
    # puncture force target (mean, sd), onset depth u0 (mean, sd, lo, hi), give-way length range
    "artery": {"F": (1.9, 0.2, 1.4, 2.5), "u0": (4.0 * MM, 0.8 * MM, 2.5 * MM, 6.0 * MM),
               "L": (0.5 * MM, 3.0 * MM), "beta": (0.2, 0.45), "Fc": (0.4, 0.9), "lc": (0.5 * MM, 1.5 * MM),
               "friction": "phantom"},
    "skin": {"F": (4.8, 0.3, 4.0, 5.6), "u0": (8.0 * MM, 0.9 * MM, 6.0 * MM, 10.5 * MM),
             "L": (0.3 * MM, 1.0 * MM), "beta": (0.15, 0.35), "Fc": (0.6, 1.2), "lc": (0.7 * MM, 1.5 * MM),
             "friction": "phantom"},
    "liver": {"F": (2.3, 0.25, 1.7, 2.9), "u0": (10.0 * MM, 1.0 * MM, 8.0 * MM, 12.5 * MM),
              "L": (0.0, 0.0), "beta": None, "Fc": None, "lc": (0.1 * MM, 0.3 * MM), "friction": "liver"},
}


def draw_trial(rng, ds, trial):
    name, protocol, tissue, laws, relax, internal = ds
    T = TISSUE[tissue]
    P = {"trial": trial}
    law = laws[trial % len(laws)]
    F_target = tgauss(rng, *T["F"])
    u0 = tgauss(rng, *T["u0"])
    if tissue == "liver":
        up = u0
        beta = 48.0 * up / (48.0 * up + 5200.0 * up * up)   # shape of the paper's liver 1 capsule
    else:
        beta = rng.uniform(*T["beta"])
    wall = Wall(law, u0, beta, rng, T["L"])

    # friction per unit length
    f = lambda: 1.0 + 0.1 * rng.gauss(0.0, 1.0)
    if T["friction"] == "liver":
        fr = {"Cp": 10.57 * f(), "Cn": -11.96 * f(), "bp": 904.0 * f(), "bn": 458.0 * f(),
              "Dp": 18.45 * f(), "Dn": -18.23 * f()}
        Fc = tgauss(rng, 0.94, 0.15, 0.5, 1.4)
    else:
        Cp = rng.uniform(35.0, 85.0)
        fr = {"Cp": Cp, "Cn": -Cp * rng.uniform(0.85, 1.15), "bp": rng.uniform(600, 1200),
              "bn": rng.uniform(300, 700)}
        fr["Dp"] = fr["Cp"] * rng.uniform(1.2, 1.6)
        fr["Dn"] = fr["Cn"] * rng.uniform(1.2, 1.6)
        Fc = rng.uniform(*T["Fc"])
    lc = rng.uniform(*T["lc"])
    rho = rng.uniform(0.4, 0.6)
    drag_frac = rng.uniform(0.5, 0.9)

    # relaxation
    if relax is None:
        K = NO_KERNEL
    elif relax == "prony12":
        K = prony_kernel(rng, rng.choice([1, 2]))
    elif relax == "prony2":
        K = prony_kernel(rng, 2)
    elif relax == "qlv":
        K = qlv_kernel(rng)
    elif relax == "power_law":
        K = power_kernel(rng)
    else:
        raise ValueError(relax)

    # protocol
    x_start = rng.uniform(0.0, 20.0) * MM
    if protocol == "idw":
        pre = rng.uniform(2.0, 15.0) * MM
        v = rng.choice([1.0, 2.0, 3.0]) * MM
        depth = 25.0 * MM
        fs = rng.uniform(75.0, 120.0)
        jit = rng.uniform(0.02, 0.04)
        p_gap = rng.uniform(0.001, 0.004)
        noise = rng.uniform(0.010, 0.014)
        tare = rng.gauss(0.0, 0.004)
    else:
        pre = rng.uniform(3.0, 10.0) * MM
        v = rng.uniform(2.0, 6.0) * MM
        depth = rng.uniform(25.0, 40.0) * MM
        fs = 250.0
        jit = 0.005
        p_gap = 0.0
        noise = rng.uniform(0.0025, 0.0035)
        tare = rng.gauss(0.0, 0.002)
    xs1 = x_start + pre
    # tissue dragged out on withdrawal: force back to zero d before the surface (inside the start gap)
    drag_d = rng.uniform(1.5 * MM, max(1.5 * MM, min(9.0 * MM, pre - 0.5 * MM)))
    acc = v / rng.uniform(0.03, 0.08)
    M = Motion(x_start)
    M.rest(rng.uniform(0.5, 1.5))
    M.move(xs1 + depth, v, acc)
    marks = {}
    if protocol == "idw":
        marks["hold"] = (M.t, M.t + HOLD_S)
        M.rest(HOLD_S)
    else:
        dw = rng.uniform(1.0, 2.0)
        marks["hold"] = (M.t, M.t + dw)
        M.rest(dw)
        A = rng.uniform(2.0, 4.0) * MM
        fo = rng.uniform(0.2, 1.2)
        cyc = rng.choice([2.0, 2.5])
        marks["osc"] = (M.t, M.t + cyc / fo, A, fo, cyc)
        M.osc(A, fo, cyc)
        M.rest(rng.uniform(1.0, 2.0))
    marks["withdraw"] = (M.t, M.x)
    M.move(x_start, v, acc)
    M.rest(rng.uniform(0.5, 1.0))

    # internal vessel walls (liver only)
    vessels = []
    if internal:
        nw = rng.choice([1, 2])
        pos = u0 + rng.uniform(2.0, 4.0) * MM        # contact point past the surface
        for j in range(nw):
            w0 = rng.uniform(1.0, 2.5) * MM
            vlaw = rng.choice(["multilayer", "weibull_damage"])
            vw = Wall(vlaw, w0, rng.uniform(0.2, 0.5), rng, (0.5 * MM, 1.5 * MM))
            Fv = rng.uniform(0.4, 0.9)
            if pos + vw.u_th > 24.0 * MM:
                break
            vessels.append({"x_contact": xs1 + pos, "wall": vw, "F": Fv})
            pos = pos + vw.u_th + rng.uniform(1.0, 2.5) * MM

    ts = sample_times(rng, M.t, fs, jit, p_gap)
    P.update(dict(law=law, F_target=F_target, u0=u0, wall=wall, fr=fr, Fc=Fc, lc=lc, rho=rho,
                  drag_d=drag_d, drag_frac=drag_frac, K=K, x_start=x_start, xs1=xs1, v=v, depth=depth,
                  fs=fs, jit=jit, p_gap=p_gap, noise=noise, tare=tare, acc=acc, motion=M, marks=marks,
                  vessels=vessels, ts=ts, protocol=protocol))
    return P


def simulate(P):
    """Returns per-sample lists: x, A (normalised first-wall part), B (everything else), through index."""
    M, wall, K, fr = P["motion"], P["wall"], P["K"], P["fr"]
    xs1 = P["xs1"]
    x_on = xs1 + wall.u_on
    xs3 = xs1 + P["rho"] * wall.u_on
    x_exit = xs1 - P["drag_d"]
    t_w0, x_w0 = P["marks"]["withdraw"]
    kappa = min(0.95, (xs3 - x_exit) / (P["drag_frac"] * (x_w0 - x_exit)))
    Fc, lc = P["Fc"], P["lc"]
    hw = Hered(K)
    ves = [(v["x_contact"], v["wall"], v["F"], Hered(K), [False]) for v in P["vessels"]]
    xs, As, Bs = [], [], []
    through_i = None
    umax = 0.0
    x_max = -1e9
    mode = "stick"
    held_fr = held_cut = 0.0
    t_stick = 0.0
    cut_scale = 1.0
    fr_prev = cut_prev = 0.0
    exited = False
    t_prev = P["ts"][0]
    for t in P["ts"]:
        dt = max(t - t_prev, 1e-6)
        t_prev = t
        x, v = M.eval(t)
        xs.append(x)
        if exited:
            As.append(0.0)
            Bs.append(0.0)
            continue
        u = x - xs1
        if u > umax:
            umax = u
        # first wall
        A = 0.0
        if through_i is None:
            phi, p, thr = wall.factor(umax, u)
            r = hw.step(wall.sigma(u), dt)
            if thr:
                through_i = len(As)
                p = 1.0
            else:
                A = phi * r
        else:
            p = 1.0
        B = 0.0
        if p > 0.0:
            # surface (dragged out on the final withdrawal)
            if t > t_w0 and x < x_w0:
                xsurf = max(x_exit, xs3 - kappa * (x_w0 - x))
            else:
                xsurf = xs3
            l = x - xsurf
            if l <= 0.0 and t > t_w0:
                exited = True
                As.append(0.0)
                Bs.append(0.0)
                continue
            l = max(l, 0.0)
            if x > x_max:
                x_max = x
            build = 1.0 - math.exp(-max(0.0, x_max - x_on) / lc)
            if v >= DV2:
                if mode == "stick":
                    cut_scale = held_cut_scale * K.G(t_stick_last - t_stick)
                mode = "fwd"
                ffr = (fr["Cp"] + fr["bp"] * v) * l
                if x >= x_max - 1e-12:
                    cut_scale = 1.0
                c = clip(x - x_max + TIP_LEN, 0.0, TIP_LEN) / TIP_LEN
                cut = Fc * build * c * cut_scale
            elif v <= -DV2:
                if mode == "stick":
                    cut_scale = held_cut_scale * K.G(t_stick_last - t_stick)
                mode = "bwd"
                ffr = (fr["Cn"] + fr["bn"] * v) * l
                c = clip(x - x_max + TIP_LEN, 0.0, TIP_LEN) / TIP_LEN
                cut = Fc * build * c * cut_scale
            else:
                if mode != "stick":
                    mode = "stick"
                    t_stick = t
                    held_fr = clip(fr_prev, fr["Dn"] * l, fr["Dp"] * l)
                    held_cut = cut_prev
                    held_cut_scale = cut_scale
                t_stick_last = t
                g = K.G(t - t_stick)
                ffr = held_fr * g
                cut = held_cut * g
            fr_prev, cut_prev = ffr, cut
            B = p * (ffr + cut)
        else:
            held_cut_scale = 1.0
            t_stick_last = t_stick = t
        # internal walls
        for xc, vw, Fv, hv, broken in ves:
            if broken[0]:
                continue
            w = x - xc
            if w <= 0:
                continue
            wm = w  # insertion only reaches walls while advancing
            phi, pv, thr = vw.factor(wm, w)
            r = hv.step(Fv * vw.sigma(w), dt)
            if thr:
                broken[0] = True
                continue
            B += phi * r
        As.append(A)
        Bs.append(B)
    return xs, As, Bs, through_i


def solve_scale(As, Bs, ti, target):
    idx = [i for i in range(ti + 1) if As[i] > 0.0]
    bmax = max(Bs[: ti + 1]) if ti is not None else 0.0
    lo, hi = 0.0, 10.0 * target
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        m = max(bmax, max(mid * As[i] + Bs[i] for i in idx))
        if m < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


ARTERY_MAX_DROP = 0.25  # N over two sample intervals: the artery has no sharp first fall


def giveway_max_drop(f, xs, P, ti):
    x_on = P["xs1"] + P["wall"].u_on
    i_on = next(i for i, x in enumerate(xs) if x >= x_on)
    return max([f[j] - f[min(j + 2, ti)] for j in range(max(0, i_on - 2), ti)] + [0.0])


def r6(v):
    return round(v, 6)


def run_dataset(ds, out_dir, seed, ntrials):
    name, protocol, tissue, laws, relax, internal = ds
    d = os.path.join(out_dir, name)
    os.makedirs(d, exist_ok=True)
    punct, peaks, trials_info = [], [], []
    for k in range(ntrials):
        rng = random.Random("fourth-apart:%d:%s:%d" % (seed, name, k))
        for attempt in range(40):
            P = draw_trial(rng, ds, k)
            xs, As, Bs, ti = simulate(P)
            s = solve_scale(As, Bs, ti, P["F_target"])
            f = [s * a + b for a, b in zip(As, Bs)]
            ts = P["ts"]
            if tissue != "artery" or giveway_max_drop(f, xs, P, ti) <= ARTERY_MAX_DROP:
                break
        pf = max(f[: ti + 1])
        pk = max(f)
        punct.append(round(pf, 6))
        peaks.append(round(pk, 6))
        # noise after the physics so it does not shift the drawn parameters
        lines = ["t_s,x_m,f_n"]
        nz, tare = P["noise"], P["tare"]
        for t, x, fv in zip(ts, xs, f):
            lines.append("%.4f,%.6f,%.5f" % (t, round(x * 1e6) / 1e6, fv + tare + rng.gauss(0.0, nz)))
        with open(os.path.join(d, "trial_%03d.csv" % k), "w") as fh:
            fh.write("\n".join(lines) + "\n")
        # per-trial truth
        h0, h1 = P["marks"]["hold"]
        ih0 = next(i for i, t in enumerate(ts) if t >= h0 + 1e-9)
        ih1 = max(i for i, t in enumerate(ts) if t <= h1 - 1e-9)
        hold_fall = 1.0 - f[ih1] / f[ih0] if f[ih0] > 0 else None
        t_w0 = P["marks"]["withdraw"][0]
        iz = next((i for i, t in enumerate(ts) if t > t_w0 and f[i] == 0.0), None)
        wmin = min(f[i] for i, t in enumerate(ts) if t > t_w0)
        wall = P["wall"]
        info = {
            "trial": k,
            "redraws": attempt,
            "giveway_max_two_sample_drop_n": round(giveway_max_drop(f, xs, P, ti), 5),
            "first_wall": wall.describe(),
            "first_wall_scale_n": r6(s),
            "puncture_target_n": r6(P["F_target"]),
            "x_surface_m": r6(P["xs1"]), "x_start_m": r6(P["x_start"]),
            "x_giveway_onset_m": r6(P["xs1"] + wall.u_on),
            "x_through_m": r6(xs[ti]), "t_through_s": ts[ti], "through_sample": ti,
            "x_surface_relaxed_m": r6(P["xs1"] + P["rho"] * wall.u_on), "rho": round(P["rho"], 4),
            "speed_m_s": r6(P["v"]), "accel_m_s2": round(P["acc"], 5), "depth_past_surface_m": r6(P["depth"]),
            "sample_rate_hz": round(P["fs"], 3), "jitter_sd_frac": round(P["jit"], 4),
            "gap_prob": round(P["p_gap"], 5), "noise_sd_n": round(P["noise"], 5), "tare_n": round(P["tare"], 5),
            "friction_n_per_m": {k2: round(v2, 4) for k2, v2 in P["fr"].items()},
            "cutting_force_n": round(P["Fc"], 4), "cutting_buildup_len_m": r6(P["lc"]),
            "tip_compression_len_m": TIP_LEN,
            "drag_exit_before_surface_m": r6(P["drag_d"]), "x_withdrawal_exit_m": r6(P["xs1"] - P["drag_d"]),
            "drag_fraction_of_travel": round(P["drag_frac"], 4),
            "relaxation": P["K"].describe(),
            "hold_t_s": [round(h0, 4), round(h1, 4)],
            "hold_fall_frac_noisefree": None if hold_fall is None else round(hold_fall, 4),
            "withdrawal_start_t_s": round(t_w0, 4),
            "withdrawal_min_force_n": round(wmin, 5),
            "x_force_returns_zero_m": None if iz is None else r6(xs[iz]),
            "n_samples": len(ts),
        }
        if "osc" in P["marks"]:
            o = P["marks"]["osc"]
            info["oscillation"] = {"t_s": [round(o[0], 4), round(o[1], 4)], "amplitude_m": r6(o[2]),
                                   "form": "x = x_c - A (1 - cos(2 pi f t))", "freq_hz": round(o[3], 4),
                                   "cycles": o[4]}
        if P["vessels"]:
            info["internal_walls"] = [{"x_contact_m": r6(vv["x_contact"]), "peak_scale_n": round(vv["F"], 4),
                                       **vv["wall"].describe()} for vv in P["vessels"]]
        trials_info.append(info)

    forms = {
        "baseline": ("Okamura/Simone/O'Leary 2004 structure: zero before the surface; first wall loads as "
                     "sigma(u) = beta z + (1-beta) z^2, z = u/u0 (normalised) times a per-trial scale fixed so the "
                     "noise-free puncture force equals a drawn target; after the wall gives way the surface relaxes "
                     "to x_s3 = x_s1 + rho (x_on - x_s1); shaft friction per unit length l = x - x_s3: forward "
                     "(Cp + bp v) l, backward (Cn + bn v) l, Karnopp static band |v| < 5 um/s holding the last "
                     "friction clipped to [Dn l, Dp l]; tip cutting Fc (1 - exp(-(x_max - x_on)/lc)) carried by a "
                     "0.2 mm tip compression (unloads on retraction, held at rest); during give-way friction and "
                     "cutting are weighted by the failed fraction p; on the final withdrawal the surface is dragged "
                     "out kinematically (x_surf = max(x_exit, x_s3 - kappa (x_w0 - x))) so the force returns to zero "
                     "at x_exit = x_s1 - d, d 1.5-9 mm"),
        "first_wall": {lw: LAW_TEXT[lw] for lw in laws},
        "first_wall_law_per_trial": "laws cycled by trial index: %s" % laws,
    }
    effects = []
    if internal:
        effects.append("internal_structures")
        forms["internal_structures"] = ("1-2 vessel walls below the capsule (stage contact 2-4 mm past the "
                                        "capsule puncture depth, next wall 1-2.5 mm after the previous is through), "
                                        "each loading F_v (beta z + (1-beta) z^2), z = w/w0, w0 1-2.5 mm, F_v 0.4-0.9 N, "
                                        "giving way by a multilayer (3 layers) or Weibull damage law over 0.5-1.5 mm "
                                        "(multilayer: per-layer 0.3-0.7 mm); cutting and friction continue meanwhile")
    if relax is not None:
        effects.append("viscoelasticity")
        kind = {"prony12": "Prony series, 1 or 2 branches (one: tau 1.3-1.8 s; two: tau1 0.4-0.9 s, tau2 1.8-3.5 s)",
                "prony2": "Prony series, 2 branches (tau1 0.4-0.9 s, tau2 1.8-3.5 s)",
                "qlv": "Fung QLV, box spectrum tau1 0.05-0.2 s, tau2 2.5-5 s, C solved (16-node quadrature)",
                "power_law": "power law G = g_inf + (1-g_inf)(1+t/t0)^-n, t0 0.3-1 s, n 0.6-1.2 (28-node spectrum)"}[relax]
        forms["viscoelasticity"] = (kind + "; weights solved so a held force falls by a drawn 34-41 % over 5 s. "
                                    "Wall (and internal wall) forces: phi * hereditary integral of the undamaged "
                                    "elastic force. Shaft friction and tip cutting: unrelaxed while sliding "
                                    "(contact renewed), relax as held_value * G(t - t_stick) at rest")
    truth = {
        "dataset": name, "protocol": protocol, "effects": effects, "forms": forms,
        "puncture_force_n": punct, "peak_force_n": peaks, "seed": seed, "tissue": tissue,
        "generator": "fourth-apart", "units": "SI; x increasing into tissue; force positive resisting insertion",
        "puncture_definition": "max noise-free force over recorded samples up to and including the sample at "
                               "which the first wall is through",
        "trials": trials_info,
    }
    with open(os.path.join(d, "truth.json"), "w") as fh:
        json.dump(truth, fh, indent=1)
    return trials_info, punct, peaks


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--only", default=None, help="comma-separated dataset names")
    a = ap.parse_args(argv)
    only = set(a.only.split(",")) if a.only else None
    t0 = time.time()
    for ds in DATASETS:
        if only and ds[0] not in only:
            continue
        info, punct, peaks = run_dataset(ds, a.out_dir, a.seed, a.trials)
        hf = [i["hold_fall_frac_noisefree"] for i in info if i["hold_fall_frac_noisefree"] is not None]
        z = [(i["x_force_returns_zero_m"] - i["x_surface_m"]) * 1e3 for i in info
             if i["x_force_returns_zero_m"] is not None]
        print("%-22s punct %.2f N  peak %.2f N  hold fall %4.1f %%  zero at %+.1f mm from surface"
              % (ds[0], sum(punct) / len(punct), sum(peaks) / len(peaks),
                 100 * sum(hf) / max(1, len(hf)), sum(z) / max(1, len(z))))
    print("done in %.1f s" % (time.time() - t0))


if __name__ == "__main__":
    main()
