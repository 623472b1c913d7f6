"""An independent fine-step reference of the pulse-driven muscle (test helper).

Written from the model's specification and the papers, not from the
production code: it shares nothing with ``hill_muscle_ros.model`` but the
force-length coefficients of the paper's Eq. 1 (through the pure helpers of
``fes_reference.py``: FL, the inverse of Eq. 3, the recruitment curves and
the unit layout of fibre types and recruitment order). The tests compare the
production model (1 ms step) against it.

What it simulates:

- **Pulses**: per channel, a list of (time [s], pulse width [s], current [A]
  or ``None``); :func:`train_pulses` writes them for a train of constant or
  stepped frequency, pulse width and current, in mode single, doublet or
  triplet. ``emd_s`` delays every pulse.
- **Recruitment per pulse**: with a current I, the Lapicque (Weiss) strength-
  duration law I PW / (PW + c) >= rheobase gives the width at the reference
  current I_ref that excites the same units, PW_eq = c k / (I_ref - k),
  k = I PW / (PW + c), and every unit for k >= I_ref; without one,
  PW_eq = PW. Then u = curve(PW_eq). Channel c owns the territory
  ``default_rng(channel_seed).permutation(N)[e_(c-1):e_c]`` (block ends
  e_c = floor(N cumsum(fractions) / sum + 0.5)); a pulse recruits the first
  floor(N_c u + 0.5) units of the territory along the muscle's recruitment
  order, last in first out. A newly recruited unit stores the CE length of
  the pulse's instant, a released one forgets it.
- **Activation** (Ding et al. 2003, J Biomech 36: 1345-1356; Muscle Nerve
  2003), per channel:
  CN' = (1 / tau_c) S(t) - CN / tau_c with S(t) = sum_(t_i <= t) R_i
  exp(-(t - t_i) / tau_c), R_1 = 1, R_i = 1 + (R0 - 1) exp(-(t_i - t_(i-1)) /
  tau_c), R0 = Km + r0_offset; x = CN / (Km + CN);
  a' = x / (tau1 + tau2) - a / (tau1 + tau2 x).
  a is Ding's force F over A (tau1 + tau2). S is exact (it decays by
  exp(-h / tau_c) and jumps by R_i at a pulse); CN and a are integrated.
- **Force**: F0 = sum over channels c of a_c(t) sum over recruited units j of
  c of f_j FL(l_o,j / l_opt) mu_j (``length: instantaneous``: FL(l_ce /
  l_opt)); the CE follows d l_CE / dt = FV_inv(f_SE, F0), and with no unit
  recruited it is free, l_CE = l_rest + dl_MT (the paper's model).
- **Fatigue** (``riener``): per unit, mu' = (mu_min - mu) a / T_fat +
  (1 - mu)(1 - a) / T_rec with a = a_c(t) while the unit is recruited by
  channel c and a = 0 while it is not. The law is affine in mu with the same
  coefficients for every recruited unit of one channel and fibre type, so
  between two pulses of a channel its units' fitness is mu(t) = alpha(t)
  mu(t_p) + beta(t) with alpha' = -k alpha, beta' = -k beta + g, alpha(t_p)
  = 1, beta(t_p) = 0 (k = a / T_fat + (1 - a) / T_rec, g = mu_min a / T_fat +
  (1 - a) / T_rec), integrated with the rest of the state; a unit that is not
  recruited recovers by its closed form.
- **Release**: a channel whose a is below ``release_activation`` with no
  pulse for 1 s releases its units. The instant 1 s after a channel's last
  pulse is a cut of the time line; later crossings are found at the
  sub-step boundaries.

The state (l_CE, per channel CN and a, the fatigue maps) is integrated by
classic RK4 with a fixed sub-step ``dt_ref_s`` that divides the sample step,
each sub-step cut exactly at the pulses and release instants inside it
(all events are exact in time: no event is moved to a grid). dl_MT is linear
between the samples. The outputs at t_k are right-continuous (the pulses of
t_k applied).

Own error (test_ding_reference.py, 0.4 s of a 50 Hz doublet train on the
paper's muscle with a stretch): halving ``dt_ref_s`` from 1e-4 s to 5e-5 s
changes the force by 8.8e-8 N, from 2e-4 s to 1e-4 s by 1.0e-6 N: RK4 at
1e-4 s is exact to far below the tests' 0.1 N. Cost: about 12 us per
sub-step (one channel), i.e. 0.12 s per simulated second at 1e-4 s.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from fes_reference import PARAM_DEFAULTS as LEVEL_DEFAULTS
from fes_reference import command, fl_array, fl_scalar, fv_inverse, unit_layout

#: Parameters the reference reads, with their defaults: the paper's muscle,
#: every level-model extension off, and the pulse model's published values:
#: Ding et al. 2003 (as cocofest writes it: tau_c 20 ms, tau1 50.957 ms,
#: tau2 60 ms, Km 0.103, R0 = Km + 1.04), a chronaxie of 459 us (Mogyoros,
#: Kiernan & Burke 1996) and a reference current of 40 mA.
PARAM_DEFAULTS = dict(LEVEL_DEFAULTS, **{
    'activation_model': 'ding2003', 'channel_fractions': (1.0,), 'channel_seed': 1,
    'chronaxie_s': 459e-6, 'current_ref_a': 0.040, 'ding_tau_c_s': 0.020,
    'ding_tau1_s': 0.050957, 'ding_tau2_s': 0.060, 'ding_km': 0.103, 'ding_r0_offset': 1.04,
    'release_activation': 1e-4,
})

#: Fields of the stimulator that shape the trains, not the muscle: the
#: reference takes the pulses themselves and ignores them.
TRAIN_FIELDS = ('frequency_hz', 'stimulator', 'burst_interval_s')

#: Ding et al. 2003's scaling factor A [N/s] (rested), as cocofest writes it.
DING_A_N_PER_S = 3009.0

#: [s] A channel with no pulse for this long releases its units once its
#: activation is below ``release_activation``.
RELEASE_AFTER_S = 1.0

#: Pulses per burst in each train mode.
PULSES_PER_BURST = {'single': 1, 'doublet': 2, 'triplet': 3}

#: [s] Two instants closer than this are one (float noise of sums of periods
#: and sample times, far below any time scale of the model).
TIME_EPS_S = 1e-12

#: Outputs, one array per name at the sample instants (``activation`` and
#: ``cn``: one column per channel).
OUTPUTS = ('force_n', 'l_ce_m', 'eff_f_iso_n', 'recruitment', 'mean_fitness', 'activation',
           'cn')


def _params(given: dict) -> dict:
    """The given parameters over :data:`PARAM_DEFAULTS`, checked."""
    given = {k: v for k, v in given.items() if k not in TRAIN_FIELDS}
    unknown = sorted(set(given) - set(PARAM_DEFAULTS))
    if unknown:
        raise ValueError(f'unknown parameter `{unknown[0]}` (known: {", ".join(PARAM_DEFAULTS)})')
    p = dict(PARAM_DEFAULTS)
    p.update(given)
    if p['activation_model'] != 'ding2003':
        raise ValueError(f'this reference models `activation_model: ding2003` only, got '
                         f'{p["activation_model"]!r}')
    if p['units'] != 'multi' or p['tau_act_s'] != 0.0 or p['tau_deact_s'] != 0.0:
        raise ValueError('ding2003 takes `units` multi and `tau_act_s` = `tau_deact_s` = 0')
    if p['unit_length_spread'] != 0.0:
        raise ValueError('this reference models `unit_length_spread` 0 only')
    for key, choices in (('length', ('initial', 'instantaneous')),
                         ('fatigue', ('none', 'riener')),
                         ('fv_scaling', ('absolute', 'relative'))):
        if p[key] not in choices:
            raise ValueError(f'`{key}` must be one of {", ".join(choices)}, got {p[key]!r}')
    return p


def equivalent_pulse_width(pulse_width_s: float, current_a: float | None, current_ref_a: float,
                           chronaxie_s: float) -> float:
    """[s] The width at ``current_ref_a`` that excites the units a pulse of
    (``current_a``, ``pulse_width_s``) excites, by the Lapicque (Weiss)
    strength-duration law: a unit of rheobase r fires if I PW / (PW + c) >= r.

    :param pulse_width_s: [s] pulse width PW
    :param current_a: [A] pulse current I, or ``None`` for the reference current
    :param current_ref_a: [A] current I_ref at which the recruitment curve holds
    :param chronaxie_s: [s] chronaxie c
    :return: PW_eq = c k / (I_ref - k), k = I PW / (PW + c); ``math.inf`` when
        k >= I_ref (every unit); PW itself without a current
    """
    if current_a is None:
        return pulse_width_s
    k = current_a * pulse_width_s / (pulse_width_s + chronaxie_s)
    if k >= current_ref_a:
        return math.inf
    return chronaxie_s * k / (current_ref_a - k)


def pulse_command(p: dict, pulse_width_s: float, current_a: float | None) -> float:
    """[-] u of one pulse: the recruitment curve of its equivalent width, in [0, 1]."""
    pw_eq = equivalent_pulse_width(pulse_width_s, current_a, p['current_ref_a'],
                                   p['chronaxie_s'])
    if math.isinf(pw_eq):
        return 1.0
    return float(command(p, np.array([pw_eq]), 'pulse_width_s')[0])


def channel_territories(p: dict, order: np.ndarray) -> list[np.ndarray]:
    """Each channel's units as positions along the muscle's recruitment order.

    :param p: parameters (``n_units``, ``channel_fractions``, ``channel_seed``)
    :param order: 0-based unit index at each position of the recruitment order
    :return: per channel, the ascending positions (in the order) of its units
    """
    n = int(p['n_units'])
    fractions = np.asarray(p['channel_fractions'], dtype=float).ravel()
    ends = np.floor(n * np.cumsum(fractions) / fractions.sum() + 0.5).astype(int)
    starts = np.concatenate(([0], ends[:-1]))
    perm = np.random.default_rng(p['channel_seed']).permutation(n)
    position_of_unit = np.empty(n, dtype=int)
    position_of_unit[order] = np.arange(n)
    return [np.sort(position_of_unit[perm[s:e]]) for s, e in zip(starts, ends)]


def _steps(value, name: str) -> list[tuple[float, float]]:
    """A piecewise-constant track as [(t_from, value), ...] from 0 (a number: held)."""
    if value is None:
        return []
    if isinstance(value, (int, float)):
        return [(0.0, float(value))]
    steps = [(float(t), float(v)) for t, v in value]
    if not steps or steps[0][0] != 0.0 or any(b[0] < a[0] for a, b in zip(steps, steps[1:])):
        raise ValueError(f'`{name}` must be a number or (t_from, value) steps from 0, '
                         f'got {value!r}')
    return steps


def _held(steps: list[tuple[float, float]], t_s: float) -> float:
    """The value of a step track at ``t_s`` (right-continuous)."""
    value = steps[0][1]
    for t_from, v in steps:
        if t_from <= t_s + TIME_EPS_S:
            value = v
    return value


def train_pulses(duration_s: float, frequency_hz, pulse_width_s, current_a=None,
                 mode: str = 'single',
                 burst_interval_s: float = 0.005) -> list[tuple[float, float, float | None]]:
    """The pulses of one channel's train in [0, ``duration_s``).

    Each track is a number (held) or piecewise-constant steps [(t_from [s],
    value), ...] from 0. The channel stimulates while PW > 0 (and I > 0 if a
    current is given). A train starts with a burst at the instant its
    stimulation becomes non-zero; the next burst comes 1 / f after the
    previous one, f read at the previous burst (a run at one frequency is
    t_a + n / f from its first burst t_a). A burst is 1, 2 or 3 pulses
    ``burst_interval_s`` apart, all with the PW and I of its first pulse; a
    stimulation that stops cuts the rest of it.

    :param duration_s: [s] end of the train (excluded)
    :param frequency_hz: [Hz] burst frequency f
    :param pulse_width_s: [s] pulse width PW
    :param current_a: [A] pulse current I, or ``None`` (the pulses carry ``None``)
    :param mode: ``single``, ``doublet`` or ``triplet``
    :param burst_interval_s: [s] interval between the pulses of a burst
    :return: (time [s], PW [s], I [A] or ``None``) in time order
    """
    f_steps = _steps(frequency_hz, 'frequency_hz')
    pw_steps = _steps(pulse_width_s, 'pulse_width_s')
    i_steps = _steps(current_a, 'current_a')
    n_burst = PULSES_PER_BURST[mode]

    def on(t: float) -> bool:
        return _held(pw_steps, t) > 0.0 and (not i_steps or _held(i_steps, t) > 0.0)

    # The stimulation is constant between the step times of PW and I: its
    # on-intervals [start, stop) begin and end there.
    switches = sorted({t for t, _ in pw_steps} | {t for t, _ in i_steps} | {duration_s})
    intervals: list[list[float]] = []
    for a, b in zip(switches, switches[1:]):
        if a >= duration_s or not on(a):
            continue
        if intervals and intervals[-1][1] == a:
            intervals[-1][1] = b
        else:
            intervals.append([a, b])
    pulses: list[tuple[float, float, float | None]] = []
    for start, stop in intervals:
        anchor, f_run, n = start, _held(f_steps, start), 0
        t_burst = start
        while t_burst < stop - TIME_EPS_S:
            f = _held(f_steps, t_burst)
            if f != f_run:
                anchor, f_run, n = t_burst, f, 0
            pw = _held(pw_steps, t_burst)
            current = _held(i_steps, t_burst) if i_steps else None
            for m in range(n_burst):
                t_pulse = t_burst + m * burst_interval_s
                if t_pulse < stop - TIME_EPS_S:
                    pulses.append((t_pulse, pw, current))
            n += 1
            t_burst = anchor + n / f_run
    return pulses


def ding_force(pulse_times_s: Sequence[float], t_s: np.ndarray, a_n_per_s: float = DING_A_N_PER_S,
               tau_c_s: float = 0.020, tau1_s: float = 0.050957, tau2_s: float = 0.060,
               km: float = 0.103, r0_offset: float = 1.04,
               dt_ref_s: float = 1e-5) -> tuple[np.ndarray, np.ndarray]:
    """Ding et al. 2003's force model alone, unnormalised, in newtons:
    CN' = (S - CN) / tau_c, F' = A x - F / (tau1 + tau2 x), x = CN / (Km + CN).

    RK4 with sub-steps of at most ``dt_ref_s``, cut at every pulse and sample.

    :param pulse_times_s: [s] the pulse instants, ascending
    :param t_s: [s] sample instants, ascending, from 0
    :param a_n_per_s: [N/s] scaling factor A
    :return: CN [-] and F [N] at the samples (after the pulses of that instant)
    """
    times = [float(t) for t in pulse_times_s]
    r0 = km + r0_offset
    cn, force, s_sum = 0.0, 0.0, 0.0
    t_now, last = 0.0, None
    i = 0
    out_cn, out_f = np.empty(len(t_s)), np.empty(len(t_s))

    def rates(s_value: float, cn_v: float, f_v: float) -> tuple[float, float]:
        x = cn_v / (km + cn_v)
        return (s_value - cn_v) / tau_c_s, a_n_per_s * x - f_v / (tau1_s + tau2_s * x)

    for k, t_k in enumerate(np.asarray(t_s, dtype=float)):
        while True:
            while i < len(times) and times[i] <= t_now + TIME_EPS_S:
                r_i = 1.0 if last is None else 1.0 + (r0 - 1.0) * math.exp(-(times[i] - last)
                                                                            / tau_c_s)
                s_sum += r_i
                last = times[i]
                i += 1
            if t_now >= t_k - TIME_EPS_S:
                break
            t_next = min(t_k, t_now + dt_ref_s, times[i] if i < len(times) else math.inf)
            h = t_next - t_now
            s_mid, s_end = s_sum * math.exp(-0.5 * h / tau_c_s), s_sum * math.exp(-h / tau_c_s)
            c1, f1 = rates(s_sum, cn, force)
            c2, f2 = rates(s_mid, cn + 0.5 * h * c1, force + 0.5 * h * f1)
            c3, f3 = rates(s_mid, cn + 0.5 * h * c2, force + 0.5 * h * f2)
            c4, f4 = rates(s_end, cn + h * c3, force + h * f3)
            cn += h * (c1 + 2.0 * c2 + 2.0 * c3 + c4) / 6.0
            force += h * (f1 + 2.0 * f2 + 2.0 * f3 + f4) / 6.0
            s_sum, t_now = s_end, t_next
        out_cn[k], out_f[k] = cn, force
    return out_cn, out_f


def ding_reference(params: dict, pulses: Sequence[Sequence[tuple]], dl_mt_m: np.ndarray,
                   dt_s: float = 1e-3, dt_ref_s: float = 1e-4) -> dict[str, np.ndarray]:
    """Simulate the pulse-driven muscle on the sample grid t_k = k ``dt_s``.

    :param params: parameter values by field name; missing keys take
        :data:`PARAM_DEFAULTS`; ``frequency_hz``, ``stimulator`` and
        ``burst_interval_s`` are ignored (the pulses are given)
    :param pulses: per channel, its pulses (time [s], PW [s], I [A] or
        ``None``); ``emd_s`` delays them
    :param dl_mt_m: [m] MTU length change at the samples, linear between them
    :param dt_s: [s] sample step
    :param dt_ref_s: [s] RK4 sub-step; must divide ``dt_s``
    :return: arrays at the samples: ``force_n`` [N] (f_SE + f_PE), ``l_ce_m``
        [m], ``eff_f_iso_n`` [N] (F0), ``recruitment`` (recruited units / N),
        ``mean_fitness``, ``activation`` and ``cn`` (samples x channels)
    """
    p = _params(params)
    dl_mt = np.asarray(dl_mt_m, dtype=float).tolist()
    n_sub = int(round(dt_s / dt_ref_s))
    if n_sub < 1 or abs(n_sub * dt_ref_s - dt_s) > 1e-9 * dt_s:
        raise ValueError(f'`dt_ref_s` must divide the sample step {dt_s!r} s, got {dt_ref_s!r}')
    h_sub = dt_s / n_sub
    n = int(p['n_units'])
    layout = unit_layout(p)
    order, unit_type, f_max = layout['unit'], layout['type'], layout['f_max']
    n_types = int(unit_type.max()) + 1
    mu_min_k = [float(layout['mu_min'][unit_type == k][0]) for k in range(n_types)]
    tau_f_k = [float(layout['tau_f'][unit_type == k][0]) for k in range(n_types)]
    tau_r_k = [float(layout['tau_r'][unit_type == k][0]) for k in range(n_types)]
    territories = channel_territories(p, order)
    n_ch = len(territories)
    if len(pulses) != n_ch:
        raise ValueError(f'`pulses` needs one list per channel ({n_ch}), got {len(pulses)}')
    fatigue = p['fatigue'] == 'riener'
    initial = p['length'] == 'initial'
    relative = p['fv_scaling'] == 'relative'
    f_iso, l_opt, l_rest = p['f_iso_max_n'], p['l_opt_m'], p['l_rest_m']
    k_se, k_pe = p['k_se_n_per_m'], p['k_pe_n_per_m']
    fv_a, fv_b, fv_ae, fv_be = p['fv_a_n'], p['fv_b_m_per_s'], p['fv_a_ecc_n'], \
        p['fv_b_ecc_m_per_s']
    tau_c, tau1, tau2 = p['ding_tau_c_s'], p['ding_tau1_s'], p['ding_tau2_s']
    km, r0 = p['ding_km'], p['ding_km'] + p['ding_r0_offset']
    release_a = p['release_activation']

    # Events: pulses (delayed by emd) and the candidate release instants, 1 s
    # after a pulse that no other pulse of its channel follows within 1 s.
    events: list[tuple[float, int, int, float, float | None]] = []   # (t, kind, c, pw, i)
    for c, channel in enumerate(pulses):
        times = [float(t) + p['emd_s'] for t, _, _ in channel]
        for j, (t_p, (_, pw, current)) in enumerate(zip(times, channel)):
            events.append((t_p, 0, c, float(pw), current))
            if j + 1 == len(times) or times[j + 1] - t_p > RELEASE_AFTER_S:
                events.append((t_p + RELEASE_AFTER_S, 1, c, 0.0, None))
    events.sort(key=lambda e: (e[0], e[1], e[2]))

    # -- state -------------------------------------------------------------------
    # y: l_CE, then per channel CN and a, then (fatigue) per channel and type
    # the affine fitness map (alpha, beta) since the channel's last pulse.
    n_y = 1 + 2 * n_ch + (2 * n_ch * n_types if fatigue else 0)
    y = [0.0] * n_y
    y[0] = l_rest + dl_mt[0]
    i_map = [[1 + 2 * n_ch + 2 * (c * n_types + k) for k in range(n_types)]
             for c in range(n_ch)]
    if fatigue:
        for c in range(n_ch):
            for k in range(n_types):
                y[i_map[c][k]] = 1.0
    s_sum = [0.0] * n_ch                 # S per channel
    last_pulse: list[float | None] = [None] * n_ch
    n_rec = [0] * n_ch                   # recruited units of each channel's territory
    mu = np.ones(n)                      # fitness per position (recruited: at the last flush)
    t_mu = np.zeros(n)                   # when an unrecruited position's mu was last set
    channel_of = np.full(n, -1)          # recruiting channel per position, -1 if none
    l_o = np.full(n, np.nan)             # stored length per position
    weight = np.zeros(n)                 # f_j FL(l_o,j / l_opt) (initial) or f_j
    tau_r_pos = layout['tau_r']
    # Per channel and type: sum of weight mu (at the flush) and of weight.
    p_sum = [[0.0] * n_types for _ in range(n_ch)]
    q_sum = [[0.0] * n_types for _ in range(n_ch)]

    def recovered(positions: np.ndarray, t: float) -> np.ndarray:
        """Fitness at ``t`` of unrecruited positions (exact recovery)."""
        return 1.0 - (1.0 - mu[positions]) * np.exp(-(t - t_mu[positions])
                                                     / tau_r_pos[positions])

    def flush(c: int) -> None:
        """Apply channel c's fitness maps to its recruited units and reset them."""
        if not fatigue:
            return
        pos = territories[c][:n_rec[c]]
        for k in range(n_types):
            ia = i_map[c][k]
            sel = pos[unit_type[pos] == k]
            mu[sel] = y[ia] * mu[sel] + y[ia + 1]
            y[ia], y[ia + 1] = 1.0, 0.0

    def set_channel(c: int, m_new: int, t: float) -> None:
        """Recruit or release so that the first ``m_new`` units of channel c's
        territory are recruited, new ones at the CE length now."""
        flush(c)
        pos = territories[c]
        old = n_rec[c]
        if m_new > old:
            new = pos[old:m_new]
            if fatigue:
                mu[new] = recovered(new, t)
            l_o[new] = y[0]
            channel_of[new] = c
            weight[new] = f_max[new] * (fl_array(l_o[new] / l_opt) if initial else 1.0)
        elif m_new < old:
            gone = pos[m_new:old]
            t_mu[gone] = t
            l_o[gone] = np.nan
            channel_of[gone] = -1
            weight[gone] = 0.0
        n_rec[c] = m_new
        rec = pos[:m_new]
        for k in range(n_types):
            sel = rec[unit_type[rec] == k]
            q_sum[c][k] = float(weight[sel].sum())
            p_sum[c][k] = float(weight[sel] @ mu[sel])

    def any_recruited() -> bool:
        return any(m > 0 for m in n_rec)

    def eff_f_iso(state: list[float]) -> float:
        """[N] F0 of a state vector (the recruitment and flushed fitness now)."""
        total = 0.0
        for c in range(n_ch):
            if n_rec[c] == 0:
                continue
            a_c = state[2 + 2 * c]
            if fatigue:
                g = 0.0
                for k in range(n_types):
                    ia = i_map[c][k]
                    g += state[ia] * p_sum[c][k] + state[ia + 1] * q_sum[c][k]
            else:
                g = q_sum[c][0] if n_types == 1 else sum(q_sum[c])
            total += a_c * g
        if not initial:
            total *= fl_scalar(state[0] / l_opt)
        return total

    def derivative(state: list[float], s_values: list[float], dl_now: float,
                   slope: float, free: bool) -> list[float]:
        """d state / dt at one stage (S given exactly)."""
        d = [0.0] * n_y
        for c in range(n_ch):
            cn, a_c = state[1 + 2 * c], state[2 + 2 * c]
            d[1 + 2 * c] = (s_values[c] - cn) / tau_c
            x = cn / (km + cn)
            d[2 + 2 * c] = x / (tau1 + tau2) - a_c / (tau1 + tau2 * x)
            if fatigue:
                a_f = a_c if n_rec[c] > 0 else 0.0
                for k in range(n_types):
                    ia = i_map[c][k]
                    rate = a_f / tau_f_k[k] + (1.0 - a_f) / tau_r_k[k]
                    gain = mu_min_k[k] * a_f / tau_f_k[k] + (1.0 - a_f) / tau_r_k[k]
                    d[ia] = -rate * state[ia]
                    d[ia + 1] = gain - rate * state[ia + 1]
        if free:
            d[0] = slope
            return d
        f0 = eff_f_iso(state)
        if f0 <= 0.0:
            d[0] = slope
            return d
        ca = fv_a * f0 / f_iso if relative else fv_a
        cae = fv_ae * f0 / f_iso if relative else fv_ae
        stretch = dl_now - state[0] + l_rest
        d[0] = fv_inverse(k_se * stretch if stretch > 0.0 else 0.0, f0, ca, fv_b, cae, fv_be)
        return d

    def rk4(h: float, dl0: float, slope: float) -> None:
        """One RK4 step of length ``h`` of the whole state; S decays exactly."""
        free = not any_recruited()
        s_mid = [s * math.exp(-0.5 * h / tau_c) for s in s_sum]
        s_end = [s * math.exp(-h / tau_c) for s in s_sum]
        k1 = derivative(y, s_sum, dl0, slope, free)
        y2 = [v + 0.5 * h * dv for v, dv in zip(y, k1)]
        k2 = derivative(y2, s_mid, dl0 + 0.5 * h * slope, slope, free)
        y3 = [v + 0.5 * h * dv for v, dv in zip(y, k2)]
        k3 = derivative(y3, s_mid, dl0 + 0.5 * h * slope, slope, free)
        y4 = [v + h * dv for v, dv in zip(y, k3)]
        k4 = derivative(y4, s_end, dl0 + h * slope, slope, free)
        for j in range(n_y):
            y[j] += h * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]) / 6.0
        s_sum[:] = s_end
        if free:
            y[0] = l_rest + dl0 + h * slope

    def apply_event(event: tuple, t: float, dl_now: float) -> None:
        """A pulse (kind 0) or a release check (kind 1) at ``t``."""
        _, kind, c, pw, current = event
        if kind == 1:
            maybe_release(t)
            return
        if not any_recruited():
            y[0] = l_rest + dl_now          # the free CE, exactly
        r_i = 1.0 if last_pulse[c] is None else \
            1.0 + (r0 - 1.0) * math.exp(-(t - last_pulse[c]) / tau_c)
        s_sum[c] += r_i
        last_pulse[c] = t
        u = pulse_command(p, pw, current)
        set_channel(c, math.floor(len(territories[c]) * u + 0.5), t)

    def maybe_release(t: float) -> None:
        for c in range(n_ch):
            if n_rec[c] > 0 and last_pulse[c] is not None \
                    and t - last_pulse[c] >= RELEASE_AFTER_S - TIME_EPS_S \
                    and y[2 + 2 * c] < release_a:
                set_channel(c, 0, t)

    def mean_fitness(t: float) -> float:
        if not fatigue:
            return 1.0
        values = np.empty(n)
        free_pos = np.flatnonzero(channel_of < 0)
        values[free_pos] = recovered(free_pos, t)
        for c in range(n_ch):
            pos = territories[c][:n_rec[c]]
            for k in range(n_types):
                ia = i_map[c][k]
                sel = pos[unit_type[pos] == k]
                values[sel] = y[ia] * mu[sel] + y[ia + 1]
        return float(values.mean())

    n_samples = len(dl_mt)
    out = {name: np.empty(n_samples) for name in OUTPUTS}
    out['activation'] = np.empty((n_samples, n_ch))
    out['cn'] = np.empty((n_samples, n_ch))
    i_ev = 0
    for k in range(n_samples):
        t_k = k * dt_s
        last = k == n_samples - 1
        slope = 0.0 if last else (dl_mt[k + 1] - dl_mt[k]) / dt_s
        # Events at t_k (right-continuous outputs), then the sample.
        while i_ev < len(events) and events[i_ev][0] <= t_k + TIME_EPS_S:
            apply_event(events[i_ev], t_k, dl_mt[k])
            i_ev += 1
        if not any_recruited():
            y[0] = l_rest + dl_mt[k]
        stretch = dl_mt[k] - (y[0] - l_rest)
        out['force_n'][k] = k_se * max(0.0, stretch) + k_pe * max(0.0, dl_mt[k])
        out['l_ce_m'][k] = y[0]
        out['eff_f_iso_n'][k] = eff_f_iso(y) if any_recruited() else 0.0
        out['recruitment'][k] = sum(n_rec) / n
        out['mean_fitness'][k] = mean_fitness(t_k)
        out['activation'][k] = [y[2 + 2 * c] for c in range(n_ch)]
        out['cn'][k] = [y[1 + 2 * c] for c in range(n_ch)]
        if last:
            break
        # The step [t_k, t_k + dt): sub-steps cut at the events inside it.
        t_end = (k + 1) * dt_s
        cuts = [t_k + j * h_sub for j in range(1, n_sub)]
        j_ev = i_ev
        while j_ev < len(events) and events[j_ev][0] < t_end - TIME_EPS_S:
            cuts.append(events[j_ev][0])
            j_ev += 1
        cuts = sorted(cuts) + [t_end]
        t_now = t_k
        for t_cut in cuts:
            h = t_cut - t_now
            if h > TIME_EPS_S:
                rk4(h, dl_mt[k] + slope * (t_now - t_k), slope)
                t_now = t_cut
                if t_cut < t_end:
                    maybe_release(t_now)
            while i_ev < len(events) and events[i_ev][0] <= t_now + TIME_EPS_S \
                    and t_now < t_end - TIME_EPS_S:
                apply_event(events[i_ev], t_now, dl_mt[k] + slope * (t_now - t_k))
                i_ev += 1
        # Release crossings at the step's end are checked before the sample.
        maybe_release(t_end)
    return out
