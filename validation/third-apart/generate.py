#!/usr/bin/env python3
"""Independent validation-data generator for needle-insertion analyses ("third-apart").

    python3 generate.py OUT_DIR [--seed N] [--trials 10]

Writes OUT_DIR/<dataset>/trial_000.csv ... (header t_s,x_m,f_n) and
OUT_DIR/<dataset>/truth.json for 15 datasets.  Python 3 standard library only.

VALIDATION ONLY: never use these files (or this code's numbers) to tune an analysis.
See README.md for every physics choice and its source.
"""
import argparse
import json
import math
import os
import random
import sys
import time

MM = 1e-3
ENC_STEP = 1e-6          # stage encoder step [m]
INF = float("inf")


# --------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------
def lognorm(rng, mean, cv):
    """Log-normal draw with the given mean and coefficient of variation."""
    if cv <= 0:
        return mean
    s2 = math.log(1.0 + cv * cv)
    return mean * math.exp(rng.gauss(-0.5 * s2, math.sqrt(s2)))


def clip(v, lo, hi):
    return lo if v < lo else (hi if v > hi else v)


def solve_quad(a1, a2, f):
    """u >= 0 with a1*u + a2*u^2 = f."""
    if a2 <= 0:
        return f / a1
    return (-a1 + math.sqrt(a1 * a1 + 4.0 * a2 * f)) / (2.0 * a2)


def powerlaw_prony(alpha, t0, nbins=10, lo=-3.5, hi=1.5):
    """Prony (sum of exponentials) representation of (1 + t/t0)^-alpha.

    Exact Laplace representation: (1+t/t0)^-a = E_s[exp(-s t/t0)], s ~ Gamma(a, 1).
    The Gamma distribution is cut into log-spaced bins; each bin becomes one
    exponential term (weight = bin mass, rate = geometric bin centre / t0).
    Returns (weights, taus)."""
    lg = math.lgamma(alpha)

    def pdf_log(y):  # density of log(s)
        s = math.exp(y)
        return math.exp(alpha * y - s - lg)

    step = (hi - lo) / nbins
    ln10 = math.log(10.0)
    w, taus = [], []
    smin = 10.0 ** lo
    m_low = smin ** alpha / (alpha * math.exp(lg))  # mass below smin (e^-s ~ 1)
    w.append(m_low)
    taus.append(t0 / (smin * 10 ** (-0.25)))
    for i in range(nbins):
        a = (lo + i * step) * ln10
        b = (lo + (i + 1) * step) * ln10
        n = 40
        h = (b - a) / n
        m = sum(pdf_log(a + (j + 0.5) * h) for j in range(n)) * h
        w.append(m)
        taus.append(t0 / (10.0 ** (lo + (i + 0.5) * step)))
    rest = max(0.0, 1.0 - sum(w))
    w.append(rest)
    taus.append(t0 / (10.0 ** (hi + 0.25)))
    tot = sum(w)
    return [x / tot for x in w], taus


# --------------------------------------------------------------------------
# stage trajectory (trapezoidal moves, holds, raised-cosine strokes)
# --------------------------------------------------------------------------
class Traj:
    def __init__(self, x0, amax):
        self.segs = []
        self.t = 0.0
        self.x = x0
        self.amax = amax

    def hold(self, dur):
        self.segs.append((self.t, self.t + dur, 0, (self.x,)))
        self.t += dur

    def move(self, x1, vmax):
        D = x1 - self.x
        sgn = 1.0 if D >= 0 else -1.0
        D = abs(D)
        a = self.amax
        ta = vmax / a
        if a * ta * ta > D:
            ta = math.sqrt(D / a)
            vp = a * ta
            tc = 0.0
        else:
            vp = vmax
            tc = (D - a * ta * ta) / vmax
        dur = 2 * ta + tc
        self.segs.append((self.t, self.t + dur, 1, (self.x, sgn, a, ta, tc, vp, D, dur)))
        self.t += dur
        self.x = x1

    def stroke(self, A, f, ncyc):
        """x = xc - A (1 - cos wt): starts and ends at rest at xc, moves outward."""
        dur = ncyc / f
        self.segs.append((self.t, self.t + dur, 2, (self.x, A, 2 * math.pi * f)))
        self.t += dur

    def evaluator(self):
        segs = self.segs
        state = [0]
        nseg = len(segs)

        def ev(t):
            i = state[0]
            while i < nseg - 1 and t >= segs[i][1]:
                i += 1
            state[0] = i
            t0, t1, kind, p = segs[i]
            if t > t1:
                t = t1
            tau = t - t0
            if kind == 0:
                return p[0], 0.0
            if kind == 1:
                x0, sgn, a, ta, tc, vp, D, dur = p
                if tau < ta:
                    s = 0.5 * a * tau * tau
                    v = a * tau
                elif tau < ta + tc:
                    s = 0.5 * a * ta * ta + vp * (tau - ta)
                    v = vp
                else:
                    r = max(0.0, dur - tau)
                    s = D - 0.5 * a * r * r
                    v = a * r
                return x0 + sgn * s, sgn * v
            xc, A, w = p
            return xc - A * (1.0 - math.cos(w * tau)), -A * w * math.sin(w * tau)
        return ev


# --------------------------------------------------------------------------
# the tissue: paper baseline + optional effects
# --------------------------------------------------------------------------
class Tissue:
    """1-D needle/tissue interaction.  step() returns the force the tissue
    exerts on the needle (positive = resisting insertion)."""

    def __init__(self, P):
        self.P = P
        self.s0 = P["s0"]
        self.u_p = P["u_p"]
        self.punct = False
        self.exited = False
        self.d_prev = None
        self.t_p = None
        # capsule
        self.cap_kind = P["cap_kind"]
        # relaxation (Prony terms, normalised so G(0) = 1)
        self.visco = P.get("visco")
        if self.visco:
            self.g = list(P["visco"]["g"])
            self.tau = list(P["visco"]["tau"])
            self.ginf = P["visco"]["ginf"]
            self.h = [0.0] * len(self.g)       # QLV states of the capsule
            self.fe_prev = 0.0
            self.r = [0.0] * len(self.g)       # tip-renewal states
            self.q = [0.0] * len(self.g)       # held-friction relaxation states
            self.kappa_cap = P["visco"]["kappa_cap"]
            self.R_nom = P["visco"]["R_nom"]
            self.delta_r = P["visco"]["delta_r"]
        # friction
        self.fmodel = P["fric_model"]
        self.stick = False
        self.F_hold = 0.0
        self.fr_prev = 0.0
        self.FD = 0.0   # Dahl state
        self.z = 0.0    # LuGre bristle state
        # structures
        self.structs = [dict(s) for s in P.get("structs", [])]
        for s in self.structs:
            s["intact"] = True
            s["res"] = 0.0
        # tent
        self.tent = P.get("tent")
        self.z_surf = 0.0
        self.rim_f = 0.0
        self.motion = P.get("motion")
        self.d_cut = 0.0
        self.F_res = 0.0

    # ---- elastic capsule curve ------------------------------------------
    def cap(self, u):
        P = self.P
        if u <= 0.0:
            return 0.0
        if self.cap_kind == "poly":
            return P["a1"] * u + P["a2"] * u * u
        uy, df, de, eps, Fpk = P["u_y"], P["d_flat"], P["d_ease"], P["eps_ease"], P["F_pk_el"]
        if u <= uy:
            f = P["a1"] * u + P["a2"] * u * u
        elif u <= uy + df:
            s = u - uy
            py = P["a1"] * uy + P["a2"] * uy * uy
            dpy = P["a1"] + 2 * P["a2"] * uy
            f = py + dpy * s - dpy / (2 * df) * s * s
        else:
            s = u - uy - df
            f = Fpk * (1.0 - eps * s / de) if de > 0 else Fpk
        for (ud, ed, wd) in P.get("dips", []):
            x = (u - ud) / wd
            if x * x < 25:
                f *= 1.0 - ed * math.exp(-x * x)
        return f

    def cut(self, dp):
        P = self.P
        kind = P["cut_kind"]
        if kind == "const":
            return P["f_cut"]
        if kind == "linear":
            return P["f_cut"] * (1.0 + P["cut_gamma"] * dp)
        # rise-then-ease (phantoms)
        c0, cpk, cend, lam, de, we = P["c0"], P["c_pk"], P["c_end"], P["c_lam"], P["c_de"], P["c_we"]
        c = c0 + (cpk - c0) * (1.0 - math.exp(-dp / lam))
        x = clip((dp - de) / we, 0.0, 1.0)
        S = x * x * (3 - 2 * x)
        return c - (cpk - cend) * S

    # ---- friction ---------------------------------------------------------
    def friction(self, vr, dx, l, dt):
        P = self.P
        rim = self.tent["rim"] if self.tent else 0.0
        hl = min(1.0, l / 0.3e-3) if rim else 0.0
        m = self.fmodel
        if m == "karnopp" or m == "karnopp_pow":
            dvh = P["dvh"]
            if vr >= dvh:
                if m == "karnopp":
                    visc = P["bp"] * vr
                else:
                    visc = P["bp_ref"] * P["v_ref"] * (vr / P["v_ref"]) ** P["n_pow"]
                F = (P["Cp"] + visc) * l
                self.stick = False
            elif vr <= -dvh:
                if m == "karnopp":
                    visc = P["bn"] * vr
                else:
                    visc = -P["bn_ref"] * P["v_ref"] * (-vr / P["v_ref"]) ** P["n_pow"]
                F = (P["Cn"] + visc) * l - rim * hl
                self.rim_f = -rim * hl
                self.stick = False
            else:
                lo = P["Dn"] * l - rim * hl
                hi = P["Dp"] * l
                if not self.stick:
                    self.stick = True
                    self.F_hold = clip(self.fr_prev, lo, hi)
                    if self.visco and P.get("relax_friction"):
                        self.q = list(self.g)
                else:
                    self.F_hold = clip(self.F_hold, lo, hi)
                F = self.F_hold
                if self.visco and P.get("relax_friction"):
                    q = self.q
                    G = self.ginf
                    for i in range(len(q)):
                        q[i] *= math.exp(-dt / self.tau[i])
                        G += q[i]
                    F *= G
            return F
        if m == "dahl":
            if dx != 0.0:
                target = P["Cp"] * l if dx > 0 else P["Cn"] * l
                self.FD += (target - self.FD) * (1.0 - math.exp(-abs(dx) / P["dahl_delta"]))
            visc = P["bp"] * vr if vr > 0 else P["bn"] * vr
            return self.FD + visc * l
        if m == "lugre":
            s0 = P["sigma0"]
            if vr >= 0:
                g = P["Cp"] + (P["Dp"] - P["Cp"]) * math.exp(-(vr / P["vs"]) ** 2)
            else:
                g = -P["Cn"] + (-P["Dn"] + P["Cn"]) * math.exp(-(vr / P["vs"]) ** 2)
            zdot = 0.0
            if dx != 0.0:
                zss = (g / s0) if dx > 0 else -(g / s0)
                zn = zss + (self.z - zss) * math.exp(-s0 * abs(dx) / g)
                zdot = (zn - self.z) / dt if dt > 0 else 0.0
                self.z = zn
            visc = P["bp"] * vr if vr > 0 else P["bn"] * vr
            F = (s0 * self.z + P["sigma1"] * zdot + visc) * l
            if rim:
                zeta = clip(s0 * self.z / (-P["Cn"]), -1.0, 0.0)
                F += rim * hl * zeta
                self.rim_f = rim * hl * zeta
            return F
        raise ValueError(m)

    # ---- one time step ----------------------------------------------------
    def step(self, t, dt, x, v):
        if self.exited:
            return 0.0
        P = self.P
        if self.motion:
            mo = self.motion
            th = math.pi * t / mo["period"] + mo["phase"]
            c = math.cos(th)
            n2 = 2 * mo["n"]
            m = mo["b"] * (mo["cbar"] - c ** n2)
            mv = mo["b"] * n2 * c ** (n2 - 1) * math.sin(th) * math.pi / mo["period"]
        else:
            m = mv = 0.0
        d = x - self.s0 - m
        vr = v - mv
        dx = 0.0 if self.d_prev is None else d - self.d_prev
        self.d_prev = d

        if not self.punct:
            fe = self.cap(d) if d > 0 else 0.0
            if self.visco:
                dfe = fe - self.fe_prev
                self.fe_prev = fe
                F = self.ginf * fe
                h = self.h
                for i in range(len(h)):
                    xx = dt / self.tau[i]
                    e = math.exp(-xx)
                    phi = (1.0 - e) / xx if xx > 1e-9 else 1.0
                    h[i] = e * h[i] + self.g[i] * dfe * phi
                    F += h[i]
                F = max(0.0, F / self.kappa_cap)
            else:
                F = fe
            if d >= self.u_p:
                # rupture of the capsule / skin: this sample still carries the peak
                self.punct = True
                self.t_p = t
                self.d_cut = d
                self.z_surf = P["xs3_off"]
                tip0 = self.cut(0.0)
                if self.visco:
                    rho = max(v, 1e-4) / self.delta_r
                    for i in range(len(self.r)):
                        self.r[i] = self.g[i] * rho / (rho + 1.0 / self.tau[i])
                    tip0 *= (self.ginf + sum(self.r)) / self.R_nom
                l0 = d - self.z_surf
                fr0 = P.get("Cp", 0.0) * l0
                self.F_res = max(0.0, F - tip0 - fr0)
                self.fr_prev = fr0
                self.FD = fr0
                if self.fmodel == "lugre":
                    self.z = P["Cp"] / P["sigma0"]
            return F

        # ---------------- post-puncture ----------------
        adv = 0.0
        if d > self.d_cut:
            adv = d - self.d_cut
            self.d_cut = d
        dp = self.d_cut - self.u_p
        unload = 1.0 - (self.d_cut - d) / P["delta_u"]
        if unload < 0.0:
            unload = 0.0
        tipF = self.cut(dp) * unload if unload > 0 else 0.0
        tfs = P["tau_fall"]
        for s in self.structs:
            if s["intact"]:
                dl = d - s["depth"]
                if dl > 0:
                    xr = dl / s["delta"]
                    fk = s["F"] * (s["lin"] * xr + (1 - s["lin"]) * xr * xr)
                    if fk >= s["F"]:
                        s["intact"] = False
                        s["res"] = fk
                        self.events.append(("struct", t, fk))
                    else:
                        tipF += fk
            elif s["res"] > 1e-7:
                s["res"] *= math.exp(-dt / tfs)
                tipF += s["res"]
        if self.visco:
            rho = (adv / dt) / self.delta_r if dt > 0 else 0.0
            G = self.ginf
            r = self.r
            for i in range(len(r)):
                k = rho + 1.0 / self.tau[i]
                rss = self.g[i] * rho / k
                r[i] = rss + (r[i] - rss) * math.exp(-k * dt)
                G += r[i]
            tipF *= G / self.R_nom
        if self.F_res > 0.0:
            expo = 0.0
            if tfs < INF:
                expo += dt / tfs
            lf = P["lam_fall"]
            if lf < INF:
                expo += abs(dx) / lf
            self.F_res *= math.exp(-expo)
            if self.F_res < 1e-7:
                self.F_res = 0.0
        l = d - self.z_surf
        if l <= 0.0:
            self.exited = True
            self.t_exit = t
            self.x_exit = x
            return 0.0
        fr = self.friction(vr, dx, l, dt)
        self.fr_prev = fr
        if self.tent and dx != 0.0:
            # the surface is dragged by the rim grip (not by the deep shaft friction)
            target = P["xs3_off"] if fr >= 0 else min(0.0, self.rim_f) / self.tent["k"]
            self.z_surf += (target - self.z_surf) * (1.0 - math.exp(-abs(dx) / self.tent["lam"]))
        return tipF + self.F_res + fr


# --------------------------------------------------------------------------
# dataset definitions
# --------------------------------------------------------------------------
FRICTION_SETS = {
    # Okamura, Simone, O'Leary (conference): C ~ 0, b_p 904 / b_n 458 N s/m^2 averages,
    # static D_p 30.4, D_n -29.3 N/m; zero-velocity band: own choice.
    "conference": dict(Cp=0.0, Cn=0.0, bp=904.0, bn=458.0, Dp=30.4, Dn=-29.3, dvh=0.25e-3),
    # journal refit (README, "Sources relied on"; less certain): C_p 10.57, C_n -11.96,
    # D_p 18.45, D_n -18.23 N/m, band 5 um/s; damping kept from the conference paper.
    "journal": dict(Cp=10.57, Cn=-11.96, bp=904.0, bn=458.0, Dp=18.45, Dn=-18.23, dvh=5e-6),
    # silicone/gel phantoms: own values chosen so that withdrawal pulls -0.8..-2.2 N
    "phantom": dict(Cp=30.0, Cn=-38.0, bp=300.0, bn=300.0, Dp=45.0, Dn=-50.0, dvh=0.2e-3),
}

V_PAPER = 3e-3

DATASETS = [
    dict(name="paper_none", protocol="paper", tissue="liver1", fric="conference", effects=[], fs=500.0),
    dict(name="idw_none", protocol="idw", tissue="liver1", fric="conference", effects=[], fs=100.0),
    dict(name="paper_viscoelasticity", protocol="paper", tissue="liver1", fric="conference",
         effects=["viscoelasticity"], visco="prony_liver", fs=250.0),
    dict(name="idw_viscoelasticity", protocol="idw", tissue="liver1", fric="conference",
         effects=["viscoelasticity"], visco="powerlaw", fs=90.0),
    dict(name="paper_rate_dependent_friction", protocol="paper", tissue="liver2", fric="conference",
         effects=["rate_dependent_friction"], fs=250.0),
    dict(name="paper_presliding_hysteresis", protocol="paper", tissue="liver1", fric="journal",
         effects=["presliding_hysteresis"], fs=250.0),
    dict(name="idw_presliding_hysteresis", protocol="idw", tissue="liver1", fric="journal",
         effects=["presliding_hysteresis"], fs=120.0),
    dict(name="paper_holder_inertia", protocol="paper", tissue="liver1", fric="conference",
         effects=["holder_inertia"], fs=250.0),
    dict(name="paper_tissue_motion", protocol="paper", tissue="liver1", fric="journal",
         effects=["tissue_motion"], fs=250.0),
    dict(name="idw_internal_structures", protocol="idw", tissue="liver1", fric="conference",
         effects=["internal_structures"], fs=100.0),
    dict(name="idw_depth_dependent_cutting", protocol="idw", tissue="liver1", fric="conference",
         effects=["depth_dependent_cutting"], fs=75.0),
    dict(name="idw_sensor_drift", protocol="idw", tissue="liver1", fric="journal",
         effects=["sensor_drift"], fs=100.0),
    dict(name="idw_phantom_skin", protocol="idw", tissue="phantom_skin", fric="phantom",
         effects=["viscoelasticity", "depth_dependent_cutting"], visco="prony_phantom", fs=100.0),
    dict(name="idw_phantom_skin_on_muscle", protocol="idw", tissue="phantom_skin_on_muscle", fric="phantom",
         effects=["viscoelasticity", "internal_structures", "depth_dependent_cutting"],
         visco="prony_phantom", fs=90.0),
    dict(name="idw_phantom_artery", protocol="idw", tissue="phantom_artery", fric="phantom",
         effects=["viscoelasticity", "depth_dependent_cutting"], visco="prony_phantom", fs=110.0),
]

FORMS = {
    "baseline": ("Okamura et al. model: capsule f = a1*u + a2*u^2 up to puncture (depth criterion u_p "
                 "from the trial's puncture force), fast fall (tau 4-8 ms) of the stored capsule force, "
                 "constant cutting force at the tip while it advances into uncut tissue (elastic unloading "
                 "over 0.2-0.4 mm when it backs off), modified Karnopp friction per unit length of needle in "
                 "tissue (C_p/C_n + b_p/b_n*v, static band [D_n*l, D_p*l], held value inside the band), "
                 "tissue surface relaxes to x_s3 = x_s1 + r*(x_s2-x_s1), r 0.05-0.2, after puncture"),
    "idw_withdrawal": ("dragged withdrawal: a capsule/skin-rim grip (Coulomb, withdrawal only, 0.10-0.25 N liver, "
                       "0.3-0.5 N phantoms) adds to the shaft friction and pulls the surface out to "
                       "-F_rim/k_tent (2-8 mm, lag 1 mm of travel), so more needle stays in tissue; contact "
                       "lets go when the tip passes the displaced surface"),
    "prony_liver": ("Fung QLV on the capsule force with 2-term Prony reduced relaxation "
                    "G(t)=g_inf+g1 exp(-t/tau1)+g2 exp(-t/tau2), g1~0.22 tau1~0.5 s, g2~0.18 tau2~8 s; "
                    "the tip force relaxes with the same G while the tip does not cut (renewal of fresh "
                    "tissue at the tip over 0.3 mm when it cuts); held static friction relaxes with G"),
    "powerlaw": ("power-law relaxation G(t)=g_inf+(1-g_inf)(1+t/t0)^-alpha, g_inf~0.35, alpha~0.3, t0~0.1 s "
                 "(12-term exact Laplace/Prony discretisation), applied as QLV on the capsule, renewal model at "
                 "the tip and relaxation of held static friction"),
    "prony_phantom": ("2-term Prony relaxation, g1~0.34 tau1~1.5 s, g2~0.08 tau2~0.15 s (real recordings: "
                      "tau ~1.5 s, 30-47 % drop in the 5 s hold); QLV capsule, tip renewal, held friction relaxes"),
    "rate_dependent_friction": ("power-law (shear-thinning) viscous friction per unit length: "
                                "F/l = C + b_ref*v_ref*(v/v_ref)^n, n~0.3, v_ref 5 mm/s, b_p_ref 1327 (paper's "
                                "0.2 Hz value), b_n_ref 672; effective b falls with speed as in the paper's "
                                "0.2/0.8 Hz fits"),
    "presliding_dahl": ("Dahl model (exponent 1) for the Coulomb part, presliding distance 0.6-1.5 mm: "
                        "dF/dx = (F_c*sgn(dx) - F)/delta, F_c = C_p*l or C_n*l; plus viscous b*v*l; "
                        "replaces the Karnopp static band"),
    "presliding_lugre": ("LuGre: dz/dt = v - sigma0|v|z/g(v), g(v)=C+(D-C)exp(-(v/vs)^2), vs 0.1 mm/s, "
                         "F = (sigma0 z + sigma1 dz/dt + b v) l, presliding C/sigma0 0.5-1.2 mm; "
                         "rim grip follows the normalised bristle deflection"),
    "holder_inertia": ("needle holder mass 0.2-0.35 kg on a compliant mount (15-25 Hz, damping ratio "
                       "0.04-0.1) between stage and needle; the load cell reads the mount force "
                       "= tissue force + m*a; encoder reads the stage, not the needle"),
    "tissue_motion": ("Lujan breathing along the needle axis: m(t)=b*(mean - cos^(2n)(pi t/T + phi)), "
                      "b 1.5-2.5 mm, T 3.5-5 s, n 2 or 3; surface, x_s3 and uncut front move with the tissue, "
                      "friction uses needle-tissue relative velocity"),
    "internal_structures_liver": ("1-3 vessel walls beyond the capsule puncture: extra tip force "
                                  "F_k*(c*x+(1-c)*x^2), x = (d-d_k)/delta_k, delta_k 0.6-1.5 mm, rupture at "
                                  "F_k 0.35-0.9 N with a sharp fall"),
    "internal_structures_muscle": ("1-2 muscle fascia membranes after the skin: rupture at 0.45-1.1 N over "
                                   "0.8-1.8 mm loading, sharp fall"),
    "depth_cut_linear": "cutting force f_cut*(1 + gamma*d), d = depth cut past puncture, gamma ~40 /m (CV 25 %)",
    "depth_cut_rise_ease": ("cutting force c0 + (c_pk-c0)(1-exp(-d/lambda)) - (c_pk-c_end)*smoothstep((d-d_e)/w): "
                            "climbs 1.2-3.3x within ~3 mm of the puncture, then eases while the needle advances"),
    "sensor_drift": ("load-cell thermal zero drift: A*(1-exp(-t/tau_th)) + s*t, A 30-80 mN, tau_th 15-40 s, "
                     "s 0.3-1.2 mN/s, one random sign per trial; not part of the noise-free truth forces"),
}


def draw_trial(ds, rng, trial, seed):
    """Draw all parameters of one trial."""
    P = {}
    proto = ds["protocol"]
    tissue = ds["tissue"]
    fric = dict(FRICTION_SETS[ds["fric"]])
    eff = ds["effects"]
    # --- friction (common factor CV 15 %, individual 5 %)
    phi = lognorm(rng, 1.0, 0.15)
    for k in ("Cp", "Cn", "bp", "bn", "Dp", "Dn"):
        P[k] = fric[k] * phi * lognorm(rng, 1.0, 0.05)
    P["dvh"] = fric["dvh"]
    P["fric_model"] = "karnopp"

    # --- protocol kinematics
    if proto == "paper":
        x_start = 0.012 + rng.uniform(-0.5, 0.5) * MM
        s0 = x_start + rng.uniform(3.0, 8.0) * MM
        speed = V_PAPER
        umax = 30 * MM
    else:
        x_start = 0.030 + rng.uniform(-1.0, 1.0) * MM
        s0 = x_start + rng.uniform(2.0, 15.0) * MM
        speed = [1e-3, 2e-3, 3e-3][ds["_speeds"][trial]]
        umax = 20 * MM
    P["x_start"] = x_start
    P["s0"] = s0
    P["speed"] = speed

    # --- capsule / puncture / cutting
    P["tau_fall"] = rng.uniform(4e-3, 8e-3)
    P["lam_fall"] = INF
    P["delta_u"] = rng.uniform(0.2, 0.4) * MM
    P["xs3_ratio"] = rng.uniform(0.05, 0.2)
    P["cut_kind"] = "const"
    if tissue in ("liver1", "liver2"):
        P["cap_kind"] = "poly"
        for _ in range(1000):
            if tissue == "liver1":
                a1 = 48.0 * lognorm(rng, 1.0, 0.15)
                a2 = 5200.0 * lognorm(rng, 1.0, 0.15)
                Fp = 2.304 * lognorm(rng, 1.0, 0.30)
                up = solve_quad(a1, a2, Fp)
                fcut = 0.94 * lognorm(rng, 1.0, 0.30)
            else:
                a1 = 2.0 * lognorm(rng, 1.0, 0.15)
                a2 = 2300.0 * lognorm(rng, 1.0, 0.15)
                up = rng.gauss(16.65, 2.5) * MM
                Fp = a1 * up + a2 * up * up
                # paper's drop ratio 0.658/2.304 applied to liver 2's nominal puncture force
                fcut = 0.2856 * (2.0 * 16.65e-3 + 2300.0 * 16.65e-3 ** 2) * lognorm(rng, 1.0, 0.30)
            if 6 * MM <= up <= umax and fcut <= 0.7 * Fp:
                break
        P.update(a1=a1, a2=a2, F_p=Fp, u_p=up, f_cut=fcut)
    else:
        draw_phantom(P, rng, tissue, speed)
    P["xs3_off"] = P["xs3_ratio"] * P["u_p"]

    # --- idw: dragged withdrawal (tent + rim grip)
    if proto == "idw":
        rim = rng.uniform(0.3, 0.5) if tissue.startswith("phantom") else rng.uniform(0.10, 0.25)
        w_t = rng.uniform(2.0, 8.0) * MM
        P["tent_w_target"] = w_t
        P["tent"] = dict(rim=rim, k=rim / w_t, lam=1.0 * MM)

    # --- effects
    if "viscoelasticity" in eff:
        P["visco"] = draw_visco(ds["visco"], rng, P, speed)
        P["relax_friction"] = True
    if "rate_dependent_friction" in eff:
        P["fric_model"] = "karnopp_pow"
        P["n_pow"] = clip(rng.gauss(0.30, 0.05), 0.15, 0.45)
        P["v_ref"] = 5e-3
        P["bp_ref"] = 1327.0 * phi * lognorm(rng, 1.0, 0.05)
        P["bn_ref"] = 458.0 * 1327.0 / 904.0 * phi * lognorm(rng, 1.0, 0.05)
    if "presliding_hysteresis" in eff:
        if proto == "paper":
            P["fric_model"] = "dahl"
            P["dahl_delta"] = rng.uniform(0.6, 1.5) * MM
        else:
            P["fric_model"] = "lugre"
            pre = rng.uniform(0.5, 1.2) * MM
            P["sigma0"] = P["Cp"] / pre
            P["sigma1"] = P["sigma0"] * 1e-3
            P["vs"] = 0.1e-3
    if "holder_inertia" in eff:
        m = rng.uniform(0.2, 0.35)
        fn = rng.uniform(15.0, 25.0)
        zeta = rng.uniform(0.04, 0.10)
        k = m * (2 * math.pi * fn) ** 2
        P["holder"] = dict(m=m, fn=fn, zeta=zeta, k=k, c=2 * zeta * math.sqrt(k * m))
    if "tissue_motion" in eff:
        n = rng.choice([2, 3])
        cbar = 1.0
        for i in range(n):
            cbar *= (2 * i + 1) / (2 * i + 2)
        P["motion"] = dict(b=rng.uniform(1.5, 2.5) * MM, period=rng.uniform(3.5, 5.0), n=n,
                           phase=rng.uniform(0, math.pi), cbar=cbar)
    if "internal_structures" in eff and tissue == "liver1":
        P["structs"] = place_structs(rng, P, rng.choice([1, 2, 2, 3]), (0.35, 0.9), (0.6, 1.5))
    if "depth_dependent_cutting" in eff and tissue in ("liver1", "liver2"):
        P["cut_kind"] = "linear"
        P["cut_gamma"] = 40.0 * lognorm(rng, 1.0, 0.25)
    if "sensor_drift" in eff:
        sg = rng.choice([-1, 1])   # monotonic warm-up drift: both terms share one sign
        P["drift"] = dict(A=sg * rng.uniform(0.03, 0.08), tau=rng.uniform(15.0, 40.0),
                          s=sg * rng.uniform(0.3e-3, 1.2e-3))

    # --- sensor
    P["noise_sd"] = rng.uniform(2.5e-3, 3.5e-3) if proto == "paper" else rng.uniform(10e-3, 14e-3)
    P["tare"] = rng.choice([-1, 1]) * rng.uniform(1e-3, 6e-3)
    return P


def place_structs(rng, P, n, Frange, drange, dmin=1.0 * MM):
    room = 25 * MM - P["u_p"] - 1.0 * MM
    out = []
    for _ in range(n):
        for _try in range(50):
            delta = rng.uniform(*drange) * MM
            hi = room - delta
            if hi <= dmin:
                break
            dk = rng.uniform(dmin, hi)
            if all(abs(dk - o["_dk"]) > 2.0 * MM + max(delta, o["delta"]) for o in out):
                out.append(dict(_dk=dk, depth=P["u_p"] + dk, delta=delta, F=rng.uniform(*Frange),
                                lin=rng.uniform(0.2, 0.5)))
                break
    if not out:  # always at least one
        delta = drange[0] * MM
        dk = max(dmin, min(room - delta, 2.0 * MM))
        out.append(dict(_dk=dk, depth=P["u_p"] + dk, delta=delta, F=rng.uniform(*Frange),
                        lin=rng.uniform(0.2, 0.5)))
    out.sort(key=lambda s: s["depth"])
    for s in out:
        del s["_dk"]
    return out


def draw_phantom(P, rng, tissue, speed):
    fr = FRICTION_SETS["phantom"]
    if tissue == "phantom_skin":
        Fpk = 4.8 * lognorm(rng, 1.0, 0.10)
        upk = rng.gauss(10.0, 0.8) * MM
        d_flat = rng.uniform(0.3, 0.8) * MM
        eps = rng.uniform(0.01, 0.04)
        d_ease = rng.uniform(0.02, 0.4) * MM
        r_f = rng.uniform(0.22, 0.42)
        R_tot = rng.uniform(1.3, 2.8)
        E = rng.uniform(0.8, 2.2)
    elif tissue == "phantom_skin_on_muscle":
        Fpk = 5.2 * lognorm(rng, 1.0, 0.10)
        upk = rng.gauss(11.0, 1.0) * MM
        d_flat = rng.uniform(0.3, 0.8) * MM
        eps = rng.uniform(0.01, 0.04)
        d_ease = rng.uniform(0.02, 0.4) * MM
        r_f = clip(0.32 * lognorm(rng, 1.0, 0.5), 0.15, 0.5)    # muscle: ~50 % CV after the fall
        R_tot = rng.uniform(1.2, 3.0)
        E = rng.uniform(0.7, 2.5)
    else:  # artery
        Fpk = 1.9 * lognorm(rng, 1.0, 0.15)
        upk = rng.gauss(6.0, 0.6) * MM
        d_flat = rng.uniform(1.0, 1.8) * MM
        eps = 0.0
        d_ease = 0.0
        r_f = rng.uniform(0.5, 0.7)
        R_tot = rng.uniform(1.0, 1.2)
        E = rng.uniform(0.7, 1.1)
        P["lam_fall"] = rng.uniform(1.0, 2.0) * MM
        P["tau_fall"] = INF
    rho = rng.uniform(1.0, 2.0)
    u_y = upk - d_flat
    a1 = Fpk / (u_y * (1 + rho) + (1 + 2 * rho) * d_flat / 2.0)
    a2 = rho * a1 / u_y
    P.update(cap_kind="phantom", a1=a1, a2=a2, u_y=u_y, d_flat=d_flat, d_ease=d_ease, eps_ease=eps,
             F_pk_el=Fpk, F_p=Fpk, u_p=upk + d_ease)
    dips = []
    if rng.random() < 0.4:
        dips.append((rng.uniform(0.4, 0.85) * u_y, rng.uniform(0.01, 0.03), 0.1 * MM))
    P["dips"] = dips
    P["delta_u"] = rng.uniform(0.3, 0.5) * MM
    # cutting profile calibrated (nominally) to the real-recording ratios
    Cp = fr["Cp"]
    l0 = (1 - P["xs3_ratio"]) * P["u_p"]
    F_f = r_f * Fpk
    d_end = 25 * MM - P["u_p"]
    R_tot = min(R_tot, 0.85 / r_f)          # the climb stays below the puncture peak
    c0 = max(0.1, F_f - Cp * l0)
    c_pk = max(c0, R_tot * F_f - Cp * (l0 + 3 * MM))
    c_end = clip(E * F_f - Cp * (l0 + d_end), 0.15 * c0, c_pk)
    P.update(cut_kind="rise_ease", c0=c0, c_pk=c_pk, c_end=c_end, c_lam=rng.uniform(0.9, 1.5) * MM,
             c_de=rng.uniform(5.0, 9.0) * MM, c_we=rng.uniform(4.0, 8.0) * MM,
             r_f=r_f, R_tot=R_tot, E_end=E)
    if tissue == "phantom_skin_on_muscle":
        P["structs"] = place_structs(rng, P, rng.choice([1, 2]), (0.45, 1.1), (0.8, 1.8), dmin=2.5 * MM)


def draw_visco(kind, rng, P, speed):
    if kind == "prony_liver":
        g = [0.22 * lognorm(rng, 1, 0.15), 0.18 * lognorm(rng, 1, 0.15)]
        tau = [0.5 * lognorm(rng, 1, 0.10), 8.0 * lognorm(rng, 1, 0.10)]
        ginf = 1.0 - sum(g)
    elif kind == "prony_phantom":
        g = [0.34 * lognorm(rng, 1, 0.08), 0.08 * lognorm(rng, 1, 0.15)]
        tau = [1.5 * lognorm(rng, 1, 0.10), 0.15 * lognorm(rng, 1, 0.10)]
        ginf = 1.0 - sum(g)
    else:
        ginf = clip(rng.gauss(0.35, 0.04), 0.25, 0.45)
        alpha = clip(rng.gauss(0.30, 0.03), 0.2, 0.4)
        t0 = 0.1 * lognorm(rng, 1, 0.15)
        w, tau = powerlaw_prony(alpha, t0)
        g = [(1 - ginf) * x for x in w]
    # normalisations so that the paper's/measured force levels refer to the nominal speed
    T = P["u_p"] / speed
    kappa = ginf + sum(gi * ti / T * (1 - math.exp(-T / ti)) for gi, ti in zip(g, tau))
    delta_r = 0.3 * MM
    rho0 = speed / delta_r
    R_nom = ginf + sum(gi * rho0 / (rho0 + 1.0 / ti) for gi, ti in zip(g, tau))
    out = dict(kind=kind, g=g, tau=tau, ginf=ginf, kappa_cap=kappa, R_nom=R_nom, delta_r=delta_r)
    if kind == "powerlaw":
        out.update(alpha=alpha, t0=t0)
    return out


# --------------------------------------------------------------------------
# protocols
# --------------------------------------------------------------------------
def build_traj(ds, P, rng):
    if ds["protocol"] == "paper":
        tr = Traj(P["x_start"], 0.1)
        x_end = P["x_start"] + 45 * MM
        tr.hold(1.0)
        tr.move(x_end, V_PAPER)
        tr.hold(4.0)
        tr.move(x_end - 2 * MM, V_PAPER)
        tr.hold(1.5)
        A = 3 * MM
        for f, n in ((0.2, 2), (0.5, 4), (0.8, 5)):
            tr.stroke(A, f, n)
            tr.hold(1.5)
        tr.move(P["x_start"] - 2 * MM, V_PAPER)
        tr.hold(1.0)
    else:
        v = P["speed"]
        tr = Traj(P["x_start"], 0.1)
        tr.hold(rng.uniform(0.5, 1.5))
        tr.move(P["s0"] + 25 * MM + rng.gauss(0, 0.2) * MM, v)
        tr.hold(5.0)
        tr.move(min(P["x_start"], P["s0"] - 11 * MM) - rng.uniform(0.5, 2.0) * MM, v)
        tr.hold(rng.uniform(0.5, 1.0))
    return tr


def sample_times(ds, rng, T):
    fs = ds["fs"]
    if ds["protocol"] == "paper":
        n = int(T * fs) + 1
        return [i / fs for i in range(n)]
    fs_t = fs * rng.uniform(0.97, 1.03)
    out = []
    t = 0.0
    while t <= T:
        out.append(t)
        dt = clip(1.0 / fs_t * (1.0 + 0.08 * rng.gauss(0, 1)), 0.5 / fs_t, 1.6 / fs_t)
        if rng.random() < 0.004:
            dt = rng.uniform(0.035, 0.070)
        t += dt
    return out


def run_trial(ds, P, rng):
    tr = build_traj(ds, P, rng)
    ev = tr.evaluator()
    times = sample_times(ds, rng, tr.t)
    tis = Tissue(P)
    tis.events = []
    n = len(times)
    xs = [0.0] * n
    fclean = [0.0] * n
    hold = P.get("holder")
    if hold is None:
        tprev = 0.0
        step = tis.step
        for i, t in enumerate(times):
            x, v = ev(t)
            xs[i] = x
            fclean[i] = step(t, t - tprev, x, v)
            tprev = t
    else:
        m, k, c = hold["m"], hold["k"], hold["c"]
        xn, vn = ev(0.0)
        tsim = 0.0
        nsub = 2
        for i, t in enumerate(times):
            x, v = ev(t)
            xs[i] = x
            if i == 0:
                fclean[i] = tis.step(0.0, 0.0, xn, vn)
                continue
            h = (t - tsim) / nsub
            for _ in range(nsub):
                tsim += h
                xsg, vsg = ev(tsim)
                Ft = tis.step(tsim, h, xn, vn)
                Fm = k * (xsg - xn) + c * (vsg - vn)
                vn += (Fm - Ft) / m * h
                xn += vn * h
            fclean[i] = k * (x - xn) + c * (v - vn)
    return times, xs, fclean, tis


def dataset_speeds(rng, n):
    s = [i % 3 for i in range(n)]
    rng.shuffle(s)
    return s


def generate(out_dir, seed, ntrials):
    t_all = time.time()
    for ds in DATASETS:
        name = ds["name"]
        d_rng = random.Random("third-apart:%d:%s" % (seed, name))
        ds = dict(ds)
        ds["_speeds"] = dataset_speeds(d_rng, ntrials)
        odir = os.path.join(out_dir, name)
        os.makedirs(odir, exist_ok=True)
        truth = dict(dataset=name, protocol=ds["protocol"], effects=list(ds["effects"]),
                     forms=forms_for(ds), puncture_force_n=[], peak_force_n=[], seed=seed,
                     tissue=tissue_desc(ds))
        extra = dict(surface_x_m=[], puncture_time_s=[], puncture_x_m=[], speed_m_s=[],
                     exit_before_surface_m=[], sample_rate_hz_nominal=ds["fs"], noise_sd_n=[], tare_n=[],
                     structure_ruptures=[], trial_params=[])
        for k in range(ntrials):
            rng = random.Random("third-apart:%d:%s:%d" % (seed, name, k))
            P = draw_trial(ds, rng, k, seed)
            times, xs, fclean, tis = run_trial(ds, P, rng)
            # truth from the noise-free force at the recorded samples
            if tis.t_p is None:
                raise RuntimeError("%s trial %d: no puncture" % (name, k))
            ip = max(i for i, t in enumerate(times) if t <= tis.t_p + 1e-12)
            punc = max(fclean[:ip + 1])
            peak = max(fclean)
            truth["puncture_force_n"].append(round(punc, 6))
            truth["peak_force_n"].append(round(peak, 6))
            extra["surface_x_m"].append(round(P["s0"], 7))
            extra["puncture_time_s"].append(round(tis.t_p, 5))
            extra["puncture_x_m"].append(round(xs[ip], 7))
            extra["speed_m_s"].append(P["speed"])
            extra["exit_before_surface_m"].append(
                round(P["s0"] - tis.x_exit, 6) if getattr(tis, "x_exit", None) is not None else None)
            extra["noise_sd_n"].append(round(P["noise_sd"], 5))
            extra["tare_n"].append(round(P["tare"], 5))
            extra["structure_ruptures"].append([[round(e[1], 4), round(e[2], 4)] for e in tis.events])
            extra["trial_params"].append(summarise_params(P))
            # measurement
            nsd = P["noise_sd"]
            tare = P["tare"]
            dr = P.get("drift")
            lines = ["t_s,x_m,f_n"]
            gauss = rng.gauss
            for i in range(len(times)):
                t = times[i]
                f = fclean[i] + tare + gauss(0.0, nsd)
                if dr:
                    f += dr["A"] * (1.0 - math.exp(-t / dr["tau"])) + dr["s"] * t
                xq = round(xs[i] / ENC_STEP) * ENC_STEP
                lines.append("%.4f,%.6f,%.4f" % (t, xq, f))
            with open(os.path.join(odir, "trial_%03d.csv" % k), "w") as fh:
                fh.write("\n".join(lines))
                fh.write("\n")
        truth.update(extra)
        with open(os.path.join(odir, "truth.json"), "w") as fh:
            json.dump(truth, fh, indent=1, allow_nan=False, default=str)
    return time.time() - t_all


def forms_for(ds):
    f = {"baseline": FORMS["baseline"]}
    if ds["protocol"] == "idw":
        f["idw_withdrawal"] = FORMS["idw_withdrawal"]
    for e in ds["effects"]:
        if e == "viscoelasticity":
            f[e] = FORMS[ds["visco"]]
        elif e == "presliding_hysteresis":
            f[e] = FORMS["presliding_dahl"] if ds["protocol"] == "paper" else FORMS["presliding_lugre"]
        elif e == "internal_structures":
            f[e] = FORMS["internal_structures_liver"] if ds["tissue"] == "liver1" else FORMS["internal_structures_muscle"]
        elif e == "depth_dependent_cutting":
            f[e] = FORMS["depth_cut_linear"] if ds["tissue"].startswith("liver") else FORMS["depth_cut_rise_ease"]
        else:
            f[e] = FORMS[e]
    return f


def tissue_desc(ds):
    t = ds["tissue"]
    d = {
        "liver1": "bovine liver 1 (Table 1: a1 48 N/m, a2 5200 N/m^2; puncture 2.30 N CV 30 %; cutting 0.94 N CV 30 %)",
        "liver2": "bovine liver 2 (Table 1: a1 2 N/m, a2 2300 N/m^2; puncture depth 16.65 +- 2.5 mm; cutting 0.19 N)",
        "phantom_skin": "skin phantom (real-recording traits: puncture ~4.8 N, sharp fall, rise-then-ease)",
        "phantom_skin_on_muscle": "skin-on-muscle phantom (~5.2 N skin puncture, 1-2 fascia drops)",
        "phantom_artery": "3 mm artery phantom (~1.9 N, roll-over instead of a sharp fall)",
    }[t]
    return "%s; friction set: %s" % (d, ds["fric"])


def summarise_params(P):
    out = {}
    for k, v in P.items():
        if k in ("tent", "holder", "motion", "drift", "visco"):
            if isinstance(v, dict):
                out[k] = {kk: (round(vv, 6) if isinstance(vv, float) else
                               ([round(x, 6) for x in vv] if isinstance(vv, list) else vv))
                          for kk, vv in v.items()}
        elif k == "structs":
            out[k] = [{kk: round(vv, 6) for kk, vv in s.items()} for s in v]
        elif k == "dips":
            out[k] = [[round(x, 6) for x in dd] for dd in v]
        elif isinstance(v, float):
            out[k] = None if v == INF else round(v, 7)
        else:
            out[k] = v
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out_dir")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--trials", type=int, default=10)
    a = ap.parse_args(argv)
    dt = generate(a.out_dir, a.seed, a.trials)
    print("wrote %d datasets x %d trials to %s in %.1f s" % (len(DATASETS), a.trials, a.out_dir, dt))


if __name__ == "__main__":
    main()
