"""An independent fine-step reference of the FES muscle model (test helper).

Written from the model's specification, not from the production code: it
shares nothing with ``hill_muscle_ros.model`` but the parameter names and the
force-length coefficients of the paper's Eq. 1 (``curves.FL_A..FL_C``). The
tests compare the production model (1 ms step) against it.

What it simulates, per unit and in plain sub-steps of ``dt_ref_s`` (10 us):

- command: u_k = curve(PW_k) clipped to [0, 1] (or u_k = R_k for a
  ``recruitment`` input), held over [t_k, t_k + dt);
- delay: u_d(t) = u_k on [t_k + emd, t_k + dt + emd), 0 before emd. When emd
  is not on the sub-step grid, each step gets one more cut at emd mod dt, so
  the switch is exact;
- activation: on each sub-step u_d is constant and a follows its closed form
  a = u_d + (a0 - u_d) exp(-h / tau) (tau of activation when u_d > a0, else of
  deactivation; tau = 0 is a jump at the sub-step start). Exact;
- recruitment (multi): M = floor(N a + 0.5); positions 1..M of the
  recruitment order are recruited (last in, first out). A newly recruited
  position stores the CE length of that instant, a released one forgets it.
  Events are placed at the sub-step boundary nearest to their exact instant
  (M over a sub-step follows a at its midpoint), so an event is at most
  ``dt_ref_s`` / 2 off, either way; at a sample t_k the state is exact
  (events up to t_k, none after);
- fitness (fatigue ``riener``): each unit's exact exponential over the
  sub-step, towards mu_min of its type (recruited) or 1 (not recruited).
  ``single``: one fitness, whole-muscle law with a held at its exact
  mid-sub-step value;
- F0 = sum over recruited positions p of f_max,p FL(c_p l / l_opt) mu_p, with
  l the stored length (``initial``) or l_ce (``instantaneous``); single:
  F0 = a f_iso_max FL(l / l_opt) mu with a at the sub-step midpoint. F0 is
  held over the sub-step;
- CE: classic RK4 over the sub-step with F0 held and dl_MT linear within the
  sample step; F0 = 0 frees the CE: l_ce = l_rest + dl_MT.

Every quantity is right-continuous: the outputs at t_k show the state after
the events of t_k (activation jump, recruitment, memory, free CE). The run
starts at rest: a = 0 before the first event, l_ce = l_rest + dl_MT[0].

``single`` with slow deactivation (tau_deact_s > 0): the muscle is released
(a := 0, F0 = 0) when a is decaying (u_d < a) and N a < 0.5; a rising from 0
stores l_o at the instant it starts to rise.

Own error, measured as the change from halving ``dt_ref_s`` (a 2 s protocol:
exponential curve, 25 ms delay, tau_act 0.06 s, tau_deact 0.11 s, stretch and
shortening ramps): 1e-5 s vs 5e-6 s changes the force by at most 2.0e-4 N
(multi; first order in dt_ref_s, from the event placement and the held F0,
so the error at 1e-5 s is about twice that, 4e-4 N) and 6e-5 N (single).
With every FES feature off, 1e-4 s is within 3.2e-4 N of the paper's DOP853
reference (test_fes_reference.py). Cost: about 5-15 us per sub-step (N = 1000,
more with fatigue and a length spread), i.e. 1-3 s for 2 s at 1e-5 s; use
1e-4 s for long fatigue runs, where the first-order terms are ten times larger.
"""
from __future__ import annotations

import math

import numpy as np

from hill_muscle_ros.model.equations import FL_A, FL_B, FL_C

#: Parameters the reference reads, with their defaults: the paper's values
#: and the FES defaults that switch every extension off.
PARAM_DEFAULTS = {
    'f_iso_max_n': 45.0, 'k_se_n_per_m': 10000.0, 'k_pe_n_per_m': 1000.0,
    'l_rest_m': 0.125, 'l_opt_m': 0.100, 'fv_a_n': 10.0, 'fv_b_m_per_s': 0.040,
    'fv_a_ecc_n': 10.0, 'fv_b_ecc_m_per_s': 0.030, 'n_units': 1000,
    'units': 'multi', 'length': 'initial', 'pw_max_s': 0.0005,
    'recruitment_curve': 'linear', 'pw_threshold_s': 0.0, 'pw_scale_s': 194.1e-6,
    'emd_s': 0.0, 'tau_act_s': 0.0, 'tau_deact_s': 0.0, 'fv_scaling': 'absolute',
    'fatigue': 'none', 'fatigue_min': (0.2,), 'tau_fatigue_s': (30.0,),
    'tau_recovery_s': (50.0,), 'fibre_fractions': (1.0,), 'fibre_force_weights': (1.0,),
    'recruitment_order': 'size', 'recruitment_seed': 0, 'unit_length_spread': 0.0,
}

#: Allowed values of the parameters that select a variant.
CHOICES = {
    'units': ('multi', 'single'), 'length': ('initial', 'instantaneous'),
    'recruitment_curve': ('linear', 'threshold_linear', 'exponential'),
    'fv_scaling': ('absolute', 'relative'), 'fatigue': ('none', 'riener'),
    'recruitment_order': ('size', 'reverse', 'random'),
}

#: Eccentric plateau of Eq. 3 as a multiple of F0.
ECC_PLATEAU = 1.5

#: phi = (sqrt(5) - 1) / 2: the golden-ratio step of the per-unit length scale.
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0

#: Relative tolerance for "dt_ref divides dt" and for snapping the delay's
#: switch offset onto the sub-step grid (float noise of k * dt, not physics).
GRID_RTOL = 1e-9

#: Outputs, one array per name, at the sample instants.
OUTPUTS = ('force_n', 'recruitment', 'mean_fitness', 'l_ce_m', 'eff_f_iso_n', 'command')


def fl_scalar(x: float) -> float:
    """[-] FL(x) of the paper's Eq. 1, clipped at zero."""
    fl = (FL_A * x + FL_B) * x + FL_C
    return fl if fl > 0.0 else 0.0


def fl_array(x: np.ndarray) -> np.ndarray:
    """[-] FL(x) of the paper's Eq. 1 for an array, clipped at zero."""
    return np.maximum(0.0, (FL_A * x + FL_B) * x + FL_C)


def fv_inverse(f: float, f0: float, a: float, b: float, a_ecc: float, b_ecc: float) -> float:
    """[m/s] CE velocity giving CE force ``f`` [N] at isometric force ``f0`` [N]
    (inverse of Eq. 3 with the continuous eccentric branch)."""
    if f <= 0.0:
        return -f0 * b / a
    if f <= f0:
        return b * (f - f0) / (f + a)
    if f < ECC_PLATEAU * f0:
        return b_ecc * (2.0 * f - 2.0 * f0) / (3.0 * f0 - 2.0 * f + a_ecc)
    return f0 * b_ecc / a_ecc


#: Fields of the pulse model and the stimulator that a first_order muscle does not read.
PULSE_FIELDS = ('activation_model', 'channel_fractions', 'channel_seed', 'chronaxie_s',
                'current_ref_a', 'ding_tau_c_s', 'ding_tau1_s', 'ding_tau2_s', 'ding_km',
                'ding_r0_offset', 'release_activation', 'frequency_hz', 'stimulator',
                'burst_interval_s')


def _params(given: dict) -> dict:
    """The given parameters over :data:`PARAM_DEFAULTS`, checked."""
    # The pulse model (activation_model ding2003, channels, the stimulator) has
    # its own reference (ding_reference.py); this one takes the level model,
    # whose stimulator-side fields it never reads.
    if given.get('activation_model', 'first_order') != 'first_order':
        raise ValueError('this reference models `activation_model: first_order` only, got '
                         f'{given["activation_model"]!r}')
    given = {k: v for k, v in given.items() if k not in PULSE_FIELDS or k in PARAM_DEFAULTS}
    if tuple(given.pop('channel_fractions', (1.0,))) != (1.0,):
        raise ValueError('this reference models one channel')
    unknown = sorted(set(given) - set(PARAM_DEFAULTS))
    if unknown:
        raise ValueError(f'unknown parameter `{unknown[0]}` (known: {", ".join(PARAM_DEFAULTS)})')
    p = dict(PARAM_DEFAULTS)
    p.update(given)
    for key, choices in CHOICES.items():
        if p[key] not in choices:
            raise ValueError(f'`{key}` must be one of {", ".join(choices)}, got {p[key]!r}')
    if not 0.0 <= p['unit_length_spread'] < 0.5:
        raise ValueError(f'`unit_length_spread` must be in [0, 0.5), '
                         f'got {p["unit_length_spread"]!r}')
    if p['recruitment_curve'] == 'threshold_linear' and not p['pw_threshold_s'] < p['pw_max_s']:
        raise ValueError(f'`pw_threshold_s` must be below `pw_max_s` for threshold_linear, '
                         f'got {p["pw_threshold_s"]!r}')
    return p


def command(p: dict, stimulation: np.ndarray, stimulation_key: str) -> np.ndarray:
    """[-] recruitment command u_k from the stimulation samples (the recruitment curves)."""
    s = np.asarray(stimulation, dtype=float)
    if stimulation_key == 'recruitment':
        if not np.all((s >= 0.0) & (s <= 1.0)):
            raise ValueError(f'`recruitment` must be in [0, 1], got {s.min()!r}..{s.max()!r}')
        return s.copy()
    if stimulation_key != 'pulse_width_s':
        raise ValueError(f'`stimulation_key` must be recruitment or pulse_width_s, '
                         f'got {stimulation_key!r}')
    curve, th = p['recruitment_curve'], p['pw_threshold_s']
    if curve == 'linear':
        u = s / p['pw_max_s']
    elif curve == 'threshold_linear':
        u = (s - th) / (p['pw_max_s'] - th)
    else:
        u = np.where(s > th, 1.0 - np.exp(-(s - th) / p['pw_scale_s']), 0.0)
    return np.clip(u, 0.0, 1.0)


def per_type(p: dict, key: str, n_types: int) -> np.ndarray:
    """One value per fibre type; a single entry applies to every type."""
    values = np.asarray(p[key], dtype=float).ravel()
    if values.size == 1:
        return np.full(n_types, values[0])
    if values.size != n_types:
        raise ValueError(f'`{key}` needs one entry per fibre type ({n_types}), got {values.size}')
    return values


def unit_layout(p: dict) -> dict[str, np.ndarray]:
    """Per-position arrays along the recruitment order (fibre types, order, length scale).

    :return: ``type`` (fibre type index), ``f_max`` [N], ``c`` (length scale
        c_p), ``mu_min``, ``tau_f`` [s], ``tau_r`` [s], ``unit`` (0-based unit
        index at each position)
    """
    n = int(p['n_units'])
    fractions = np.asarray(p['fibre_fractions'], dtype=float).ravel()
    k = fractions.size
    # Block ends of the K types over units 1..N.
    ends = np.floor(n * np.cumsum(fractions) / fractions.sum() + 0.5).astype(int)
    unit_type = np.searchsorted(ends, np.arange(1, n + 1), side='left')
    weights = per_type(p, 'fibre_force_weights', k)
    f_max_unit = p['f_iso_max_n'] * weights[unit_type] / weights[unit_type].sum()
    if p['recruitment_order'] == 'size':
        order = np.arange(n)
    elif p['recruitment_order'] == 'reverse':
        order = np.concatenate([np.flatnonzero(unit_type == t) for t in range(k - 1, -1, -1)])
    else:
        order = np.random.default_rng(p['recruitment_seed']).permutation(n)
    positions = np.arange(1, n + 1)
    c = 1.0 + p['unit_length_spread'] * (2.0 * np.mod(positions * GOLDEN, 1.0) - 1.0)
    types = unit_type[order]
    return {
        'unit': order, 'type': types, 'f_max': f_max_unit[order], 'c': c,
        'mu_min': per_type(p, 'fatigue_min', k)[types],
        'tau_f': per_type(p, 'tau_fatigue_s', k)[types],
        'tau_r': per_type(p, 'tau_recovery_s', k)[types],
    }


def sub_steps(dt: float, dt_ref: float, emd: float) -> list[tuple[float, float, int]]:
    """Pieces of one step [t_k, t_k + dt): (offset, length, lag).

    On a piece, the delayed command is u_d = u[k - lag] (0 for a negative
    index). The pieces are the uniform sub-steps of ``dt_ref``, with one more
    cut where the delay switches inside the step, at offset emd mod dt.

    :raises ValueError: if ``dt_ref`` does not divide ``dt``
    """
    n_sub = int(round(dt / dt_ref))
    if n_sub < 1 or abs(n_sub * dt_ref - dt) > GRID_RTOL * dt:
        raise ValueError(f'`dt_ref_s` must divide the sample step {dt!r} s, got {dt_ref!r}')
    h = dt / n_sub
    whole = math.floor(emd / dt + GRID_RTOL)      # whole steps of delay
    rest = emd - whole * dt                       # switch offset inside a step
    offsets = [j * h for j in range(n_sub)]
    j_near = round(rest / h)
    if abs(rest - j_near * h) <= GRID_RTOL * dt:
        rest = j_near * h if j_near < n_sub else 0.0
        whole += 1 if j_near >= n_sub else 0
    else:
        offsets.append(rest)
        offsets.sort()
    ends = offsets[1:] + [dt]
    pieces = [(o, e - o, whole if o >= rest else whole + 1) for o, e in zip(offsets, ends)]
    return pieces


def fes_reference(params: dict, t_s: np.ndarray, stimulation: np.ndarray, stimulation_key: str,
                  dl_mt_m: np.ndarray, dt_ref_s: float = 1e-5) -> dict[str, np.ndarray]:
    """Simulate the FES muscle on a uniform sample grid with per-unit state.

    :param params: parameter values by field name; missing keys take
        :data:`PARAM_DEFAULTS`
    :param t_s: [s] sample instants t_k = k dt from 0
    :param stimulation: pulse width [s] or recruitment [-] at t_k, held over
        [t_k, t_k + dt)
    :param stimulation_key: ``pulse_width_s`` or ``recruitment``
    :param dl_mt_m: [m] MTU length change at t_k, linear between samples
    :param dt_ref_s: [s] internal sub-step; must divide dt
    :return: arrays at the samples: ``force_n`` [N] (f_SE + f_PE),
        ``recruitment`` (a), ``mean_fitness``, ``l_ce_m`` [m], ``eff_f_iso_n``
        [N] (F0), ``command`` (u_k)
    """
    p = _params(params)
    t_s = np.asarray(t_s, dtype=float)
    dl_mt = np.asarray(dl_mt_m, dtype=float)
    if t_s.ndim != 1 or t_s.size < 2 or dl_mt.shape != t_s.shape \
            or np.shape(stimulation) != t_s.shape:
        raise ValueError(f'`t_s`, `stimulation` and `dl_mt_m` must be 1-D of one length >= 2, '
                         f'got {t_s.shape}, {np.shape(stimulation)}, {dl_mt.shape}')
    dt = float(t_s[1] - t_s[0])
    if not (dt > 0 and abs(t_s[0]) <= GRID_RTOL * dt
            and np.allclose(np.diff(t_s), dt, rtol=0, atol=GRID_RTOL * dt * len(t_s))):
        raise ValueError(f'`t_s` must be a uniform grid from 0, got {t_s[:3]!r}...')
    u = command(p, stimulation, stimulation_key)
    pieces = sub_steps(dt, float(dt_ref_s), float(p['emd_s']))

    n = int(p['n_units'])
    multi = p['units'] == 'multi'
    initial = p['length'] == 'initial'
    fatigue = p['fatigue'] == 'riener'
    relative = p['fv_scaling'] == 'relative'
    layout = unit_layout(p)
    if not multi and (len(np.ravel(p['fibre_fractions'])) != 1 or p['unit_length_spread'] != 0):
        raise ValueError('`units` single takes one fibre type and `unit_length_spread` 0')
    if fatigue and (np.any(layout['tau_f'] <= 0) or np.any(layout['tau_r'] <= 0)):
        raise ValueError('`tau_fatigue_s` and `tau_recovery_s` must be positive')
    f_iso, l_opt, l_rest = p['f_iso_max_n'], p['l_opt_m'], p['l_rest_m']
    k_se, k_pe = p['k_se_n_per_m'], p['k_pe_n_per_m']
    fv_a, fv_b, fv_ae, fv_be = p['fv_a_n'], p['fv_b_m_per_s'], p['fv_a_ecc_n'], \
        p['fv_b_ecc_m_per_s']
    tau_act, tau_deact = p['tau_act_s'], p['tau_deact_s']
    f_max, c = layout['f_max'], layout['c']
    no_spread = p['unit_length_spread'] == 0

    # -- state -----------------------------------------------------------------
    a = 0.0                               # activation = recruitment R
    l_ce = l_rest + dl_mt[0]              # resting (free) CE
    n_rec = 0                             # multi: recruited positions 1..n_rec
    l_o = np.full(n, np.nan)              # multi: stored length per position
    f_stored = np.zeros(n)                # multi initial: f_max,p FL(c_p l_o,p / l_opt)
    f_sum = 0.0                           # multi, no fatigue: sum of F0 terms without FL(l_ce)
    recruited = False                     # single: l_o held
    l_o_single = math.nan
    mu = np.ones(n)                       # multi fitness per position
    mu_single = 1.0
    # Per-piece-length exact fitness update mu <- mu * decay + gain, per position.
    lengths = sorted({h for _, h, _ in pieces})
    decay_rec = {h: np.exp(-h / layout['tau_f']) for h in lengths} if fatigue else {}
    decay_free = {h: np.exp(-h / layout['tau_r']) for h in lengths} if fatigue else {}
    decay = {h: decay_free[h].copy() for h in decay_rec}
    gain = {h: 1.0 - decay_free[h] for h in decay_rec}

    def set_recruited(m_new: int) -> None:
        """Recruit or release positions so that 1..m_new are recruited (LIFO)."""
        nonlocal n_rec, f_sum
        lo, hi = min(n_rec, m_new), max(n_rec, m_new)
        if m_new > n_rec:
            l_o[lo:hi] = l_ce
            f_stored[lo:hi] = f_max[lo:hi] * fl_array(c[lo:hi] * l_o[lo:hi] / l_opt)
        else:
            l_o[lo:hi] = np.nan
            f_stored[lo:hi] = 0.0
        for h in decay:
            src_d = decay_rec[h] if m_new > n_rec else decay_free[h]
            decay[h][lo:hi] = src_d[lo:hi]
            target = layout['mu_min'][lo:hi] if m_new > n_rec else 1.0
            gain[h][lo:hi] = target * (1.0 - src_d[lo:hi])
        n_rec = m_new
        f_sum = float(f_stored[:n_rec].sum() if initial else f_max[:n_rec].sum())

    def eff_f_iso(a_single: float) -> float:
        """F0 [N] of the current state (l_ce, recruitment, fitness); single:
        at activation ``a_single``."""
        if not multi:
            if not recruited or a_single <= 0.0:
                return 0.0
            length = l_o_single if initial else l_ce
            return a_single * f_iso * fl_scalar(length / l_opt) * mu_single
        if n_rec == 0:
            return 0.0
        if initial:
            return float(f_stored[:n_rec] @ mu[:n_rec]) if fatigue else f_sum
        if no_spread:
            total = float(f_max[:n_rec] @ mu[:n_rec]) if fatigue else f_sum
            return total * fl_scalar(l_ce / l_opt)
        # Without fatigue every mu is exactly 1: f_max mu is f_max.
        weights = f_max[:n_rec] * mu[:n_rec] if fatigue else f_max[:n_rec]
        return float(weights @ fl_array(c[:n_rec] * l_ce / l_opt))

    def recruit_to(a_now: float, ud: float) -> bool:
        """Apply the recruitment events that activation ``a_now`` implies
        (``ud``: the delayed command now, which tells a decaying a).

        :return: whether a single muscle was released (then a = 0)
        """
        nonlocal a, recruited, l_o_single
        if multi:
            m_new = math.floor(n * a_now + 0.5)
            if m_new != n_rec:
                set_recruited(m_new)
            return False
        if recruited and (a_now == 0.0 or (tau_deact > 0.0 and ud < a_now
                                           and n * a_now < 0.5)):
            # Released: with slow deactivation, when the last of N units would leave.
            a, recruited, l_o_single = 0.0, False, math.nan
            return True
        if not recruited and a_now > 0.0:
            # a is above 0, or starts rising from 0 now: l_o is this instant's l_ce.
            recruited, l_o_single = True, l_ce
        return False

    def activation_decay(ud: float, h: float) -> float:
        """exp(-h / tau) of the activation over a sub-step of ``h`` [s] from now."""
        tau = tau_act if ud > a else tau_deact
        return math.exp(-h / tau) if tau > 0.0 else 0.0

    n_samples = t_s.size
    out = {name: np.empty(n_samples) for name in OUTPUTS}
    out['command'][:] = u
    # The sub-step loop reads the inputs as Python floats: arithmetic on NumPy
    # scalars gives the same IEEE results several times slower.
    u, dl_mt = u.tolist(), dl_mt.tolist()
    l_ce = float(l_ce)
    t_fat, t_rec = float(layout['tau_f'][0]), float(layout['tau_r'][0])   # single: one type
    mu_min_single = float(layout['mu_min'][0])
    for k in range(n_samples):
        last = k == n_samples - 1
        slope = 0.0 if last else (dl_mt[k + 1] - dl_mt[k]) / dt
        for i, (offset, h, lag) in enumerate(pieces):
            ud = u[k - lag] if k - lag >= 0 else 0.0
            dl0 = dl_mt[k] + slope * offset
            # -- events at the sub-step start t_j (right-continuous state) ------
            if ud > a and tau_act == 0.0 or ud < a and tau_deact == 0.0:
                a = ud                              # instantaneous (de)activation
            if i == 0:
                # The sample t_k: the exact state, events up to t_k included.
                recruit_to(a, ud)
                f0 = eff_f_iso(a)
                if f0 <= 0.0:
                    l_ce = l_rest + dl0             # free CE: the SE carries nothing
                stretch = dl0 - (l_ce - l_rest)
                out['force_n'][k] = k_se * max(0.0, stretch) + k_pe * max(0.0, dl0)
                out['recruitment'][k] = a
                out['l_ce_m'][k] = l_ce
                out['eff_f_iso_n'][k] = f0
                out['mean_fitness'][k] = (float(mu.mean()) if multi else mu_single) \
                    if fatigue else 1.0
                if last:
                    break
            # Events are placed at the sub-step boundary nearest to their exact
            # instant: those of [t_j - h/2, t_j + h/2) happen at t_j. So the
            # recruitment over the sub-step follows a at its midpoint (exact
            # closed form); single holds F0 at that midpoint value (second order).
            decay_a = activation_decay(ud, h)
            a_mid = ud + (a - ud) * math.sqrt(decay_a)
            if recruit_to(a_mid, ud):                # released: a is 0 from now
                decay_a = activation_decay(ud, h)
                a_mid = ud + (a - ud) * math.sqrt(decay_a)
                recruit_to(a_mid, ud)
            f0 = eff_f_iso(a_mid)
            # -- the sub-step: CE by RK4 with F0 held, a and mu exactly ---------
            if f0 <= 0.0:
                l_ce = l_rest + dl0 + slope * h     # free CE over the sub-step
            else:
                ca = fv_a * f0 / f_iso if relative else fv_a
                cae = fv_ae * f0 / f_iso if relative else fv_ae
                dl_mid, dl1 = dl0 + 0.5 * slope * h, dl0 + slope * h
                # f_SE = k_SE max(0, stretch) at each stage, the max written as a
                # conditional (the builtin call was a tenth of the loop's time).
                s1 = dl0 - l_ce + l_rest
                k1 = fv_inverse(k_se * s1 if s1 > 0.0 else 0.0, f0, ca, fv_b, cae, fv_be)
                s2 = dl_mid - l_ce - 0.5 * h * k1 + l_rest
                k2 = fv_inverse(k_se * s2 if s2 > 0.0 else 0.0, f0, ca, fv_b, cae, fv_be)
                s3 = dl_mid - l_ce - 0.5 * h * k2 + l_rest
                k3 = fv_inverse(k_se * s3 if s3 > 0.0 else 0.0, f0, ca, fv_b, cae, fv_be)
                s4 = dl1 - l_ce - h * k3 + l_rest
                k4 = fv_inverse(k_se * s4 if s4 > 0.0 else 0.0, f0, ca, fv_b, cae, fv_be)
                l_ce += h * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
            if fatigue:
                if multi:
                    np.multiply(mu, decay[h], out=mu)
                    mu += gain[h]
                else:
                    # Whole-muscle law with a held at its midpoint value.
                    a_f = a_mid if recruited else 0.0
                    rate = a_f / t_fat + (1.0 - a_f) / t_rec
                    mu_inf = (mu_min_single * a_f / t_fat + (1.0 - a_f) / t_rec) / rate
                    mu_single = mu_inf + (mu_single - mu_inf) * math.exp(-rate * h)
            a = ud + (a - ud) * decay_a
    return out
