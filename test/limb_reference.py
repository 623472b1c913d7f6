"""An independent fine-step reference of the limb: one joint, several muscles (test helper).

Written from the limb's specification, not from the production limb
(``hill_muscle_ros.model.limb``): the joint, the muscles' lengths and the
coupled integration are written here; per muscle it reuses only the per-unit
building blocks of the single-muscle reference (``fes_reference``: the FL and
inverse F-V curves, the parameter defaults, the unit layout along the
recruitment order and the delay's sub-step pieces).

The plant is the ``ros__parameters`` mapping of a plant file, nested:
``joint: {...}`` with every joint key given, ``muscles: [names]`` and one
section per muscle (``action``, ``moment_arm_m``, ``reference_angle_rad``
(default 0) and any muscle parameter; the others take the paper's values).

What it simulates, in plain sub-steps of ``dt_ref_s`` (20 us):

- joint: J domega/dt = sum_i s_i r_i F_i - m g l_c sin(theta) - K (theta - theta_eq)
  - B omega + tau_ext, with s_i = +1 (extensor) or -1 (flexor), F_i = f_SE + f_PE
  of muscle i and dl_MT,i = -s_i r_i (theta - theta_ref,i);
- inputs: the command u_k of each muscle (after its recruitment curve) and
  the external torque are given at t_k and held over [t_k, t_k + dt);
- delay: u_d(t) = u_k on [t_k + emd, t_k + dt + emd), 0 before emd; each
  step is cut where any muscle's delayed command switches, so the switch is
  exact;
- activation: on each piece u_d is constant and a follows its closed form
  a = u_d + (a0 - u_d) exp(-h / tau) (tau = 0: a jump at the piece start);
- recruitment (multi): M = floor(N a + 0.5) over a piece follows a at the
  piece's midpoint, i.e. each event is placed on the sub-step boundary nearest
  its exact instant; a newly recruited position stores the CE length of that
  instant (per position: ``f_max,p FL(c_p l_o,p / l_opt)``), a released one
  forgets it. Single: l_o stored when a rises from 0; with tau_deact_s > 0 it
  is released when a decays below one unit's worth (N a < 0.5);
- fitness (fatigue ``riener``): each position's exact exponential over the
  piece (recruited: towards mu_min of its type, else towards 1); single: the
  whole-muscle law with a held at its midpoint value;
- F0 of each muscle is held over the piece (``instantaneous``: with the CE
  length of the piece start);
- classic RK4 over the piece on (theta, omega, l_CE,1..n); a muscle with
  F0 = 0 is free: its SE carries nothing, its CE follows the MTU
  (l_CE = l_rest + dl_MT) and is reset onto it at the end of the piece.

The outputs at t_k show the state after the events of t_k (activation jump,
recruitment, memory, free CE): with no delay and instantaneous activation the
command of t_k acts in the sample at t_k. At t = 0: theta = theta_0, omega = 0,
every CE at l_rest + dl_MT(theta_0), nothing recruited.

A stiff CE (relaxation rate lambda = k_SE times the steepest slope of the
inverse F-V curve, which grows as 1 / F0 with ``fv_scaling: relative`` as the
last units leave) gets its sub-step cut into RK4 steps of h lambda <= 2.

Own error, measured as the change from halving ``dt_ref_s`` (2e-5 s vs 1e-5 s)
on the protocols of test_model_limb.py: at most 3.6e-4 deg and 0.022 N (see
:data:`MEASURED_SELF_ERROR`), well inside the 0.05 deg and 0.5 N asked of the
production step. Cost: about 15-25 us per sub-step for two muscles
(N = 1000), i.e. 1-1.5 s of CPU per simulated second at 2e-5 s; more while a
relative-F-V CE is stiff.
"""
from __future__ import annotations

import bisect
import math

import numpy as np

from fes_reference import (GRID_RTOL, _params, fl_array, fl_scalar, fv_inverse, sub_steps,
                           unit_layout)

#: Joint keys the reference needs, every one given in the plant (no defaults here).
JOINT_KEYS = ('inertia_kg_m2', 'mass_kg', 'com_distance_m', 'gravity_m_per_s2',
              'stiffness_n_m_per_rad', 'equilibrium_rad', 'damping_n_m_s_per_rad',
              'initial_angle_rad')
#: Keys of a muscle's section that place it on the joint (the rest are muscle parameters).
PLACEMENT_KEYS = ('action', 'moment_arm_m', 'reference_angle_rad')
#: s_i of each action.
SIGNS = {'extensor': 1.0, 'flexor': -1.0}

#: Largest h lambda of one RK4 step, lambda = k_SE times the steepest slope of
#: the inverse F-V curve (b (a + F0) / a^2 at f = 0, 2 b' (F0 + a') / a'^2 at
#: f = 1.5 F0): the CE's fastest relaxation rate. A sub-step is cut into equal
#: RK4 steps to keep h lambda below it (RK4 is stable up to 2.78 on the real
#: axis; the fast mode decays by 1/3 per step at 2). Only a stiff CE needs it:
#: with ``fv_scaling: relative`` a and a' shrink with F0, so lambda grows as
#: 1 / F0 as the last units leave. At 2e-5 s a CE of absolute F-V scaling on
#: the test knee has h lambda below 0.05.
REF_H_LAMBDA = 2.0
#: Most RK4 steps a sub-step may need (a bound on the cost): beyond it the
#: reference refuses (ValueError) rather than integrate unstably. The test
#: protocols need at most 40.
REF_MAX_CUTS = 200

#: Change of the outputs from halving dt_ref_s (2e-5 -> 1e-5 s), measured on
#: the accuracy cases of test_model_limb.py (max over the cases): [deg] angle
#: and [N] force. 6e-8 deg and 4e-5 N with ``initial`` length and no FES
#: features; the F0 held over a sub-step (``instantaneous``) and the events
#: placed on the nearest sub-step boundary (activation dynamics) are first
#: order in dt_ref_s, so the reference at 2e-5 s is off by about twice this.
MEASURED_SELF_ERROR = {'theta_deg': 3.6e-4, 'force_n': 0.022}


class _Muscle:
    """One muscle's per-unit state: activation, recruitment memory, fitness, CE length."""

    def __init__(self, name: str, section: dict) -> None:
        missing = [k for k in ('action', 'moment_arm_m') if k not in section]
        if missing:
            raise ValueError(f'muscle `{name}` lacks `{missing[0]}`')
        if section['action'] not in SIGNS:
            raise ValueError(f'`{name}.action` must be extensor or flexor, '
                             f'got {section["action"]!r}')
        self.name = name
        self.s_r = SIGNS[section['action']] * float(section['moment_arm_m'])
        self.theta_ref = float(section.get('reference_angle_rad', 0.0))
        p = _params({k: v for k, v in section.items() if k not in PLACEMENT_KEYS})
        self.p = p
        self.multi = p['units'] == 'multi'
        self.initial = p['length'] == 'initial'
        self.fatigue = p['fatigue'] == 'riener'
        self.relative = p['fv_scaling'] == 'relative'
        self.n = int(p['n_units'])
        self.f_iso, self.l_opt, self.l_rest = p['f_iso_max_n'], p['l_opt_m'], p['l_rest_m']
        self.k_se, self.k_pe = p['k_se_n_per_m'], p['k_pe_n_per_m']
        self.fv = (p['fv_a_n'], p['fv_b_m_per_s'], p['fv_a_ecc_n'], p['fv_b_ecc_m_per_s'])
        self.tau_act, self.tau_deact = p['tau_act_s'], p['tau_deact_s']
        layout = unit_layout(p)
        if not self.multi and (len(np.ravel(p['fibre_fractions'])) != 1
                               or p['unit_length_spread'] != 0):
            raise ValueError(f'`{name}`: single takes one fibre type and no length spread')
        self.f_max, self.c = layout['f_max'], layout['c']
        self.mu_min, self.tau_f, self.tau_r = layout['mu_min'], layout['tau_f'], layout['tau_r']
        # -- state ---------------------------------------------------------------------
        self.a = 0.0                      # activation = recruitment R
        self.l_ce = math.nan              # set by the limb at t = 0
        self.n_rec = 0                    # multi: positions 1..n_rec recruited
        self.l_o = np.full(self.n, np.nan)        # multi: stored CE length per position
        self.f_stored = np.zeros(self.n)          # multi: f_max,p FL(c_p l_o,p / l_opt)
        self.mu = np.ones(self.n)                 # multi: fitness per position
        self.recruited = False            # single: l_o held
        self.l_o_single = math.nan
        self.mu_single = 1.0
        self._sum_stored = 0.0            # multi: sum of f_stored over the recruited
        self._sum_max = 0.0               # multi: sum of f_max over the recruited
        self.no_spread = p['unit_length_spread'] == 0
        # Per piece length h [s]: the exact fitness map (decay, gain) per position.
        self._fitness_maps: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def dl_mt(self, theta: float) -> float:
        """[m] MTU length change at angle ``theta``: -s r (theta - theta_ref)."""
        return -self.s_r * (theta - self.theta_ref)

    def force(self, theta: float) -> float:
        """[N] f_SE + f_PE at angle ``theta`` with the current CE length."""
        dl = self.dl_mt(theta)
        return self.k_se * max(0.0, dl - (self.l_ce - self.l_rest)) + self.k_pe * max(0.0, dl)

    def recruit_to(self, a_now: float, ud: float) -> bool:
        """Apply the recruitment events that activation ``a_now`` implies, now.

        :param ud: the delayed command now (tells a decaying activation)
        :return: whether a single muscle was released (then a = 0)
        """
        if self.multi:
            m_new = math.floor(self.n * a_now + 0.5)
            if m_new == self.n_rec:
                return False    # nothing recruited or released: the sums stand
            lo, hi = sorted((self.n_rec, m_new))
            if m_new > self.n_rec:
                self.l_o[lo:hi] = self.l_ce
                self.f_stored[lo:hi] = self.f_max[lo:hi] * fl_array(
                    self.c[lo:hi] * self.l_ce / self.l_opt)
            else:
                self.l_o[lo:hi] = np.nan
                self.f_stored[lo:hi] = 0.0
            for h, (decay, gain) in self._fitness_maps.items():
                self._fitness_map(h, lo, hi, m_new > self.n_rec, decay, gain)
            self.n_rec = m_new
            # Without fatigue the sums over the recruited positions change only here.
            self._sum_stored = float(self.f_stored[:m_new].sum())
            self._sum_max = float(self.f_max[:m_new].sum())
            return False
        if self.recruited and (a_now == 0.0 or (self.tau_deact > 0.0 and ud < a_now
                                                and self.n * a_now < 0.5)):
            self.a, self.recruited, self.l_o_single = 0.0, False, math.nan
            return True
        if not self.recruited and a_now > 0.0:
            self.recruited, self.l_o_single = True, self.l_ce
        return False

    def eff_f_iso(self, a_single: float) -> float:
        """[N] F0 of the current state; single: at activation ``a_single``."""
        if not self.multi:
            if not self.recruited or a_single <= 0.0:
                return 0.0
            length = self.l_o_single if self.initial else self.l_ce
            return a_single * self.f_iso * fl_scalar(length / self.l_opt) * self.mu_single
        m = self.n_rec
        if m == 0:
            return 0.0
        if not self.fatigue and self.initial:
            return self._sum_stored
        if not self.fatigue and self.no_spread:
            return self._sum_max * fl_scalar(self.l_ce / self.l_opt)
        if self.initial:
            return float(self.f_stored[:m] @ self.mu[:m])
        return float((self.f_max[:m] * self.mu[:m]) @ fl_array(self.c[:m] * self.l_ce
                                                               / self.l_opt))

    def activation_decay(self, ud: float, h: float) -> float:
        """exp(-h / tau) of the activation over a piece of ``h`` [s] from now."""
        tau = self.tau_act if ud > self.a else self.tau_deact
        return math.exp(-h / tau) if tau > 0.0 else 0.0

    def _fitness_map(self, h: float, lo: int, hi: int, recruited: bool,
                     decay: np.ndarray, gain: np.ndarray) -> None:
        """Positions lo..hi-1 of the exact fitness map over ``h`` [s],
        mu <- mu decay + gain: towards mu_min (recruited) or 1 (not)."""
        tau = self.tau_f[lo:hi] if recruited else self.tau_r[lo:hi]
        target = self.mu_min[lo:hi] if recruited else 1.0
        decay[lo:hi] = np.exp(-h / tau)
        gain[lo:hi] = target * (1.0 - decay[lo:hi])

    def fatigue_step(self, h: float, a_mid: float) -> None:
        """Exact fitness change over a piece of ``h`` [s] with the recruitment held."""
        if not self.fatigue:
            return
        if self.multi:
            if h not in self._fitness_maps:
                decay, gain = np.empty(self.n), np.empty(self.n)
                self._fitness_map(h, 0, self.n_rec, True, decay, gain)
                self._fitness_map(h, self.n_rec, self.n, False, decay, gain)
                self._fitness_maps[h] = (decay, gain)
            decay, gain = self._fitness_maps[h]
            self.mu *= decay
            self.mu += gain
            return
        a_f = a_mid if self.recruited else 0.0
        t_f, t_r, mu_min = self.tau_f[0], self.tau_r[0], self.mu_min[0]
        rate = a_f / t_f + (1.0 - a_f) / t_r
        mu_inf = (mu_min * a_f / t_f + (1.0 - a_f) / t_r) / rate
        self.mu_single = mu_inf + (self.mu_single - mu_inf) * math.exp(-rate * h)


def _pieces(dt: float, dt_ref: float, emds: list[float]) -> list[tuple[float, float, list[int]]]:
    """Pieces of one step: (offset, length, lag of each muscle's delayed command).

    The union of every muscle's cuts (uniform sub-steps plus its delay switch).
    """
    per_muscle = [sub_steps(dt, dt_ref, emd) for emd in emds] or [sub_steps(dt, dt_ref, 0.0)]
    offsets = sorted({o for pieces in per_muscle for o, _, _ in pieces})
    merged = [offsets[0]]
    for o in offsets[1:]:
        if o - merged[-1] > GRID_RTOL * dt:
            merged.append(o)
    ends = merged[1:] + [dt]
    h_sub = dt / round(dt / dt_ref)
    out = []
    for o, e in zip(merged, ends):
        # The uniform sub-steps get one length (not k h - (k - 1) h's float
        # noise), so the exact fitness maps are computed once per length.
        h = h_sub if abs((e - o) - h_sub) <= GRID_RTOL * dt else e - o
        lags = []
        for pieces in per_muscle[:len(emds)]:
            starts = [q for q, _, _ in pieces]
            j = bisect.bisect_right(starts, o + GRID_RTOL * dt) - 1
            lags.append(pieces[j][2])
        out.append((o, h, lags))
    return out


def limb_reference(plant: dict, t_s: np.ndarray, commands: np.ndarray,
                   external_torque: np.ndarray, dt_ref_s: float = 2e-5) -> dict:
    """Simulate the limb on a uniform sample grid with per-unit muscle state.

    :param plant: the plant file's ``ros__parameters``, nested (see the module docstring)
    :param t_s: [s] sample instants t_k = k dt from 0
    :param commands: [-] shape (samples, muscles): each muscle's command u_k
        (after its recruitment curve), held over [t_k, t_k + dt)
    :param external_torque: [N m] tau_ext at t_k, held over [t_k, t_k + dt)
    :param dt_ref_s: [s] internal sub-step; must divide dt
    :return: arrays at the samples: ``theta_rad``, ``omega_rad_per_s``, and
        shape (samples, muscles): ``force_n`` [N], ``l_ce_m`` [m],
        ``recruitment`` (a), ``eff_f_iso_n`` [N]
    """
    joint = plant['joint']
    missing = [k for k in JOINT_KEYS if k not in joint]
    if missing:
        raise ValueError(f'`joint.{missing[0]}` is required by the reference')
    jp = {k: float(joint[k]) for k in JOINT_KEYS}
    muscles = [_Muscle(name, dict(plant[name])) for name in plant.get('muscles', [])]
    t_s = np.asarray(t_s, dtype=float)
    n_m = len(muscles)
    u = np.asarray(commands, dtype=float).reshape(t_s.size, n_m)
    tau_ext = np.asarray(external_torque, dtype=float)
    if t_s.ndim != 1 or t_s.size < 2 or tau_ext.shape != t_s.shape:
        raise ValueError(f'`t_s` and `external_torque` must be 1-D of one length >= 2, '
                         f'got {t_s.shape}, {tau_ext.shape}')
    dt = float(t_s[1] - t_s[0])
    if not (dt > 0 and abs(t_s[0]) <= GRID_RTOL * dt
            and np.allclose(np.diff(t_s), dt, rtol=0, atol=GRID_RTOL * dt * len(t_s))):
        raise ValueError(f'`t_s` must be a uniform grid from 0, got {t_s[:3]!r}...')
    pieces = _pieces(dt, float(dt_ref_s), [float(m.p['emd_s']) for m in muscles])

    inertia = jp['inertia_kg_m2']
    gravity_torque = jp['mass_kg'] * jp['gravity_m_per_s2'] * jp['com_distance_m']
    k_joint, theta_eq = jp['stiffness_n_m_per_rad'], jp['equilibrium_rad']
    b_joint = jp['damping_n_m_s_per_rad']
    consts = [(m.s_r, m.theta_ref, m.l_rest, m.k_se, m.k_pe) for m in muscles]

    theta, omega = jp['initial_angle_rad'], 0.0
    for m in muscles:
        m.l_ce = m.l_rest + m.dl_mt(theta)

    def derivative(th: float, om: float, ls: list[float], f0s: list[float], hills: list,
                   tau: float) -> tuple[float, list[float]]:
        """(domega/dt, dl_CE/dt of each muscle) at one RK4 stage."""
        torque = 0.0
        v = []
        for (s_r, th_ref, l_rest, k_se, k_pe), l, f0, hill in zip(consts, ls, f0s, hills):
            dl = -s_r * (th - th_ref)
            if f0 > 0.0:
                stretch = dl - (l - l_rest)
                f_se = k_se * stretch if stretch > 0.0 else 0.0
                v.append(fv_inverse(f_se, f0, *hill))
            else:
                f_se = 0.0
                v.append(-s_r * om)        # free CE: follows its MTU
            torque += s_r * (f_se + (k_pe * dl if dl > 0.0 else 0.0))
        alpha = (torque - gravity_torque * math.sin(th) - k_joint * (th - theta_eq)
                 - b_joint * om + tau) / inertia
        return alpha, v

    n_samples = t_s.size
    out = {'theta_rad': np.empty(n_samples), 'omega_rad_per_s': np.empty(n_samples),
           'force_n': np.empty((n_samples, n_m)), 'l_ce_m': np.empty((n_samples, n_m)),
           'recruitment': np.empty((n_samples, n_m)), 'eff_f_iso_n': np.empty((n_samples, n_m))}
    for k in range(n_samples):
        last = k == n_samples - 1
        tau = float(tau_ext[k])
        for i_piece, (offset, h, lags) in enumerate(pieces):
            uds = [float(u[k - lag, j]) if k - lag >= 0 else 0.0 for j, lag in enumerate(lags)]
            for m, ud in zip(muscles, uds):
                if (ud > m.a and m.tau_act == 0.0) or (ud < m.a and m.tau_deact == 0.0):
                    m.a = ud                         # instantaneous (de)activation
            if i_piece == 0:
                # The sample t_k: the state after the events of t_k.
                out['theta_rad'][k], out['omega_rad_per_s'][k] = theta, omega
                for j, (m, ud) in enumerate(zip(muscles, uds)):
                    m.recruit_to(m.a, ud)
                    f0 = m.eff_f_iso(m.a)
                    if f0 <= 0.0:
                        m.l_ce = m.l_rest + m.dl_mt(theta)
                    out['force_n'][k, j] = m.force(theta)
                    out['l_ce_m'][k, j] = m.l_ce
                    out['recruitment'][k, j] = m.a
                    out['eff_f_iso_n'][k, j] = f0
                if last:
                    break
            # The recruitment over the piece follows a at its midpoint (events
            # on the nearest boundary); F0 held over the piece.
            f0s, hills, decays, a_mids = [], [], [], []
            for m, ud in zip(muscles, uds):
                decay_a = m.activation_decay(ud, h)
                a_mid = ud + (m.a - ud) * math.sqrt(decay_a)
                if m.recruit_to(a_mid, ud):          # released: a is 0 from now
                    decay_a = m.activation_decay(ud, h)
                    a_mid = ud + (m.a - ud) * math.sqrt(decay_a)
                    m.recruit_to(a_mid, ud)
                f0 = m.eff_f_iso(a_mid)
                if f0 <= 0.0:
                    m.l_ce = m.l_rest + m.dl_mt(theta)
                fa, fb, fae, fbe = m.fv
                if m.relative:
                    fa, fae = fa * f0 / m.f_iso, fae * f0 / m.f_iso
                f0s.append(f0)
                hills.append((fa, fb, fae, fbe))
                decays.append(decay_a)
                a_mids.append(a_mid)
            # -- classic RK4 on (theta, omega, l_CE...), cut where a CE is stiff -----------
            rate = max([m.k_se * max(hb * (ha + f0) / (ha * ha),
                                     2.0 * hbe * (f0 + hae) / (hae * hae))
                        for m, f0, (ha, hb, hae, hbe) in zip(muscles, f0s, hills) if f0 > 0.0],
                       default=0.0)
            n_cut = max(1, math.ceil(h * rate / REF_H_LAMBDA))
            if n_cut > REF_MAX_CUTS:
                raise ValueError(f'a CE is too stiff for the reference at t = '
                                 f'{t_s[k] + offset:.6g} s: {n_cut} RK4 steps per sub-step '
                                 f'needed, at most {REF_MAX_CUTS}')
            hc = h / n_cut
            ls = [m.l_ce for m in muscles]
            for _ in range(n_cut):
                a1, v1 = derivative(theta, omega, ls, f0s, hills, tau)
                th2, om2 = theta + 0.5 * hc * omega, omega + 0.5 * hc * a1
                a2, v2 = derivative(th2, om2, [l + 0.5 * hc * v for l, v in zip(ls, v1)],
                                    f0s, hills, tau)
                th3, om3 = theta + 0.5 * hc * om2, omega + 0.5 * hc * a2
                a3, v3 = derivative(th3, om3, [l + 0.5 * hc * v for l, v in zip(ls, v2)],
                                    f0s, hills, tau)
                th4, om4 = theta + hc * om3, omega + hc * a3
                a4, v4 = derivative(th4, om4, [l + hc * v for l, v in zip(ls, v3)],
                                    f0s, hills, tau)
                theta += hc * (omega + 2.0 * om2 + 2.0 * om3 + om4) / 6.0
                omega += hc * (a1 + 2.0 * a2 + 2.0 * a3 + a4) / 6.0
                ls = [l + hc * (w1 + 2.0 * w2 + 2.0 * w3 + w4) / 6.0 if f0 > 0.0
                      else m.l_rest + m.dl_mt(theta)
                      for l, w1, w2, w3, w4, f0, m in zip(ls, v1, v2, v3, v4, f0s, muscles)]
            for j, m in enumerate(muscles):
                m.l_ce = ls[j]
                m.fatigue_step(h, a_mids[j])
                m.a = uds[j] + (m.a - uds[j]) * decays[j]
    return out
