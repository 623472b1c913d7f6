"""The muscle with the FES extensions: delay, activation, per-unit fatigue,
fibre types and unit lengths (doc/model.md section 7).

State, split the way the equations split it:

- continuous: the CE length l_ce (integrated with RK4, the MTU length
  ramping linearly within a step), and for ``single`` the whole-muscle
  fitness mu (closed form);
- the activation a (closed form on each piece of constant delayed command,
  :mod:`.stimulus`) and the delay line of commands not yet in effect;
- discrete: the recruitment memory and per-unit fitness
  (:class:`~hill_muscle_ros.model.unit_pool.UnitPool`).

The step is split at the instants where the delayed command switches and where
the activation crosses a unit's recruitment level (the closed form gives
those instants), so that each unit stores the CE length of its own
recruitment instant and the force rises when it does, not at the next step.
Within each piece the integrator evaluates the effective isometric force at
the RK4 stage times, including the fatigue clocks. The curves are those of
:mod:`.equations`, called, not copied: this path is the readable one.

With every FES parameter at its default, :class:`~hill_muscle_ros.model.muscle.Muscle`
keeps the paper's specialised loop instead; the two agree to 1e-9 N (tests).
"""
from __future__ import annotations

import math
from typing import Sequence

from .equations import (MAX_EVENTS_PER_PIECE, QUASI_STATIC_RATE_PER_S, activation_at,
                        fes_velocity, fitness_at, force_length, parallel_force,
                        piece_activation, quasi_static_force, relaxation_rate, riener_limit,
                        riener_rate, rise_start, rk4_update, series_force, substep_count,
                        time_to_reach)
from .memory import recruited_units
from .muscle import Muscle, MuscleOutputs, check_dl_mt, check_recruitment
from .params import MuscleParams
from .stimulus import (DelayLine, command_from_pulse_width)
from .substeps import length_ramp, substeps_for
from .unit_pool import UnitPool


class FesMuscle(Muscle):
    """A muscle whose parameters switch on any FES extension.

    Made by ``Muscle(params)`` itself when ``params.fes_defaults`` is false;
    the public interface is :class:`Muscle`'s. The stimulation input of
    :meth:`step` and :meth:`run` is the recruitment *command* u (after the
    recruitment curve, before the delay and the activation); the
    ``recruitment`` state is the activation a = R.

    :param params: the muscle's parameters
    """

    def __init__(self, params: MuscleParams | None = None) -> None:
        self.params = p = params if params is not None else MuscleParams()
        self._multi = p.units == 'multi'
        self._initial = p.length == 'initial'
        self._pool = UnitPool(p) if self._multi else None
        self._delay = DelayLine(p.emd_s)
        self._relative = p.fv_scaling == 'relative'
        self._single_fatigue = (not self._multi) and p.fatigue == 'riener'
        # Single: with deactivation the activation only tends to 0; the muscle
        # lets go when N a falls below one half, as a multi muscle drops its
        # last unit (doc/model.md section 7.2).
        self._release_level = 0.5 / p.n_units if p.tau_deact_s > 0.0 else 0.0
        self.reset()

    # -- state -----------------------------------------------------------------

    def reset(self) -> None:
        """Return to rest: no command, a = 0, every unit fresh and unrecruited."""
        p = self.params
        self.t_s = 0.0
        self.l_ce_m = p.l_rest_m
        self.dl_mt_m = 0.0
        self.recruitment = 0.0          # a = R
        self.command = 0.0              # u, the latest command given
        self.n_recruited = 0
        self._delay.reset()
        if self._pool is not None:
            self._pool.reset()
        self._f_iso_single_n = 0.0      # single/initial: f_iso_max FL(l_o / l_opt)
        self._mu = 1.0                  # single: whole-muscle fitness
        self._v_free = 0.0
        # Piece context read by the force evaluation (single's activation).
        self._piece = (0.0, 0.0, 0.0, 1.0)   # (s0, a0, u_d, tau)
        self._mu_law = (0.0, 1.0, 1.0, 0.0)  # (s0, mu0, mu_inf, lambda)

    @property
    def n_runs(self) -> int:
        """Segments held by the unit memory (multi)."""
        return self._pool.n_segments if self._pool is not None else 0

    @property
    def mean_fitness(self) -> float:
        """[-] mean fitness of all units now (1 without fatigue)."""
        if self._pool is not None:
            return self._pool.mean_fitness(self.t_s)
        return self._mu

    def fitness_profile(self):
        """[-] fitness of every unit along the recruitment order (multi), O(N)."""
        if self._pool is None:
            raise ValueError('`fitness_profile` needs `units: multi`, got single')
        return self._pool.fitness_profile(self.t_s)

    def set_recruitment(self, recruitment: float) -> None:
        """Give the recruitment command u now (R directly, bypassing the curve).

        It takes effect after ``emd_s``, through the activation; with no delay
        and instantaneous activation, now.

        :param recruitment: [-] command u in [0, 1]
        """
        self.give_command(check_recruitment(recruitment))

    def set_pulse_width(self, pulse_width_s: float) -> None:
        """Give an FES pulse width now, through the recruitment curve.

        :param pulse_width_s: [s] stimulation pulse width (PW), >= 0
        """
        self.give_command(command_from_pulse_width(pulse_width_s, self.params))

    def give_command(self, u: float) -> None:
        """Queue command ``u`` at the current instant and apply what is due now
        (validated by the caller; a limb gives each muscle's command this way).

        :param u: [-] recruitment command in [0, 1]
        """
        self.command = u
        self._delay.push(self.t_s, u)
        # A command due now (no delay) with an instantaneous activation acts now.
        self.settle_now()

    def settle_now(self) -> None:
        """Apply a delayed command due at the current instant, if the activation
        follows it at once; a release to zero frees the CE at once."""
        u_d = self._delay.settle(self.t_s)
        if u_d != self.recruitment and self._tau(u_d) == 0.0:
            self._set_activation(u_d, self.t_s)
            self._piece = (self.t_s, u_d, u_d, 0.0)
            if self.eff_f_iso(self.l_ce_m, self.t_s) == 0.0:
                self.l_ce_m = self.params.l_rest_m + self.dl_mt_m

    def _tau(self, u_d: float) -> float:
        return self._tau_for(self.recruitment, u_d)

    def _tau_for(self, a: float, u_d: float) -> float:
        """[s] tau in force: ``tau_act_s`` while u_d > a, else ``tau_deact_s``."""
        p = self.params
        return p.tau_act_s if u_d > a else p.tau_deact_s

    # -- the force of the recruited units ------------------------------------------

    def _set_activation(self, a: float, t_s: float) -> None:
        """Set a = R at instant ``t_s`` and update the memory from l_ce now."""
        p = self.params
        if self._multi:
            m = recruited_units(a, p.n_units)
            self._pool.update(m, self.l_ce_m / p.l_opt_m, t_s)
            self.n_recruited = m
        else:
            if a == 0.0:
                self._f_iso_single_n = 0.0
            elif self.recruitment == 0.0:
                self._f_iso_single_n = p.f_iso_max_n * force_length(self.l_ce_m / p.l_opt_m)
            self.n_recruited = 1 if a > 0.0 else 0
        self.recruitment = a

    def eff_f_iso(self, l_ce_m: float | None = None, t_s: float | None = None) -> float:
        """[N] Eff.f_iso at CE length ``l_ce_m`` and instant ``t_s`` (default: now).

        Multi: the unit memory (Eq. 2 with each unit's fitness and length
        scale). Single: R mu f_iso_max FL(l_o or l_ce), R and mu following
        their closed forms within the current piece.
        """
        p = self.params
        l = self.l_ce_m if l_ce_m is None else l_ce_m
        t = self.t_s if t_s is None else t_s
        if self._multi:
            return self._pool.eff_f_iso(l / p.l_opt_m, t)
        s0, a0, u_d, tau = self._piece
        a = piece_activation(a0, u_d, tau, t - s0)
        if a <= 0.0:
            return 0.0
        if self._single_fatigue:
            m0, mu0, mu_inf, lam = self._mu_law
            mu = fitness_at(mu0, mu_inf, lam, t - m0)
        else:
            mu = 1.0
        f = self._f_iso_single_n if self._initial else p.f_iso_max_n * force_length(
            l / p.l_opt_m)
        return a * mu * f

    def _velocity(self, l: float, dl: float, f0: float) -> float:
        """[m/s] FV_inv(f_SE, F0), Eq. 3 inverted; ``relative`` scales a and a' with F0."""
        p = self.params
        return fes_velocity(l, dl, f0, p.k_se_n_per_m, p.l_rest_m, p.fv_a_n, p.fv_b_m_per_s,
                            p.fv_a_ecc_n, p.fv_b_ecc_m_per_s, p.f_iso_max_n, self._relative)

    # -- integration -----------------------------------------------------------------

    def _integrate(self, s0: float, s1: float, t0: float, dl0: float, rate: float) -> None:
        """RK4 for l_ce over [s0, s1] with the recruitment fixed; dl_MT(s) linear.

        The interval is cut into as many equal RK4 steps as stability needs
        (:func:`substep_count`): one, unless the CE is stiff. A CE relaxing at
        :data:`QUASI_STATIC_RATE_PER_S` or faster is quasi-static instead: at
        s1 its SE carries the force of Eq. 3 at the MTU's velocity ``rate``.

        :param t0: [s] start of the step; dl_MT(s) = dl0 + rate (s - t0)
        """
        h = s1 - s0
        if h <= 0.0:
            return
        self.begin_interval(s0, s1)
        peak = self.peak_rate(self.l_ce_m, dl0 + rate * (s0 - t0), s0, s1)
        if peak >= QUASI_STATIC_RATE_PER_S:
            p = self.params
            dl_b = dl0 + rate * (s1 - t0)
            f = self.quasi_static_force(rate, self.l_ce_m, s1)   # 0 if nothing is recruited
            self.l_ce_m = p.l_rest_m + dl_b - f / p.k_se_n_per_m
        else:
            n = substep_count(h, peak)
            for i in range(n):
                a = s0 + h * i / n
                b = s1 if i == n - 1 else s0 + h * (i + 1) / n
                self._rk4(a, b, t0, dl0, rate)
        self.end_interval(s1)

    def stiffness_rate(self, l_ce_m: float, dl_mt_m: float, t_s: float) -> float:
        """[1/s] |d v_CE / d l_CE| at the present force: how fast the CE relaxes.

        v_CE = FV_inv(f_SE) with f_SE = k_SE (dl_MT - l_CE + l_rest), so the
        rate is k_SE times the slope of Eq. 3's inverse at f_SE: b (a + F0) /
        (f + a)^2 when shortening, 2 b' (F0 + a') / (3 F0 - 2 f + a')^2 when
        lengthening. On the eccentric plateau the slope is 0, but the force
        leaves it onto the steepest part of the lengthening branch, so the
        plateau counts with that edge's slope. With ``fv_scaling: relative``
        the constants a and a' shrink with F0 and the rate grows as 1 / F0,
        which no fixed step can follow.
        """
        p = self.params
        return relaxation_rate(l_ce_m, dl_mt_m, self.eff_f_iso(l_ce_m, t_s), p.k_se_n_per_m,
                               p.l_rest_m, p.fv_a_n, p.fv_b_m_per_s, p.fv_a_ecc_n,
                               p.fv_b_ecc_m_per_s, p.f_iso_max_n, self._relative)

    def peak_rate(self, l_ce_m: float, dl_mt_m: float, s0: float, s1: float) -> float:
        """[1/s] the CE's relaxation rate over [s0, s1]: the largest of the rates at
        s0, mid-interval and s1 at the present CE length (F0 may rise from 0
        within the interval, and with relative constants the rate is largest
        when F0 is smallest but not zero)."""
        return max(self.stiffness_rate(l_ce_m, dl_mt_m, t)
                   for t in (s0, s0 + 0.5 * (s1 - s0), s1))   # the RK4 step's instants

    def quasi_static_force(self, v_ce_m_per_s: float, l_ce_m: float, t_s: float) -> float:
        """[N] the CE's force moving at ``v_ce_m_per_s`` with the F0 of CE length
        ``l_ce_m`` at ``t_s`` (:func:`quasi_static_force`)."""
        p = self.params
        return quasi_static_force(v_ce_m_per_s, self.eff_f_iso(l_ce_m, t_s), p.fv_a_n,
                                  p.fv_b_m_per_s, p.fv_a_ecc_n, p.fv_b_ecc_m_per_s,
                                  p.f_iso_max_n, self._relative)

    def _rk4(self, s0: float, s1: float, t0: float, dl0: float, rate: float) -> None:
        """One RK4 step of l_ce over [s0, s1] (see :meth:`_integrate`)."""
        h = s1 - s0
        p = self.params
        l = self.l_ce_m
        f0 = self.eff_f_iso(l, s0)
        dl_a = dl0 + rate * (s0 - t0)
        dl_b = dl0 + rate * (s1 - t0)
        # Single: the activation may rise from exactly 0 at s0, so the CE is
        # free at the first stage only; it is integrated when force builds up.
        f0_end = self.eff_f_iso(l, s1)
        if f0 > 0.0 or f0_end > 0.0:
            mid, dl_m = s0 + 0.5 * h, 0.5 * (dl_a + dl_b)
            velocity = self._velocity
            k1 = velocity(l, dl_a, f0)
            l2 = l + 0.5 * h * k1
            if self._initial:
                # F0 does not depend on the CE length: once per stage time.
                f0_mid = self.eff_f_iso(l2, mid)
                k2 = velocity(l2, dl_m, f0_mid)
                l3 = l + 0.5 * h * k2
                k3 = velocity(l3, dl_m, f0_mid)
                l4 = l + h * k3
                k4 = velocity(l4, dl_b, f0_end)
            else:
                k2 = velocity(l2, dl_m, self.eff_f_iso(l2, mid))
                l3 = l + 0.5 * h * k2
                k3 = velocity(l3, dl_m, self.eff_f_iso(l3, mid))
                l4 = l + h * k3
                k4 = velocity(l4, dl_b, self.eff_f_iso(l4, s1))
            l = rk4_update(l, h, k1, k2, k3, k4)
            if not self._initial and self.eff_f_iso(l, s1) == 0.0:
                l = p.l_rest_m + dl_b   # the instantaneous CE left the FL range
            elif self._initial and f0_end == 0.0:
                l = p.l_rest_m + dl_b   # single: released within the piece
        else:
            l = p.l_rest_m + dl_b       # the free CE takes up the SE slack
        self.l_ce_m = l

    def begin_interval(self, s0: float, s1: float) -> None:
        """Before integrating [s0, s1] with no recruitment change inside it:
        fix the closed form of the single muscle's fitness over the interval."""
        if self._single_fatigue:
            self._start_mu_law(s0, s1)

    def end_interval(self, s1: float) -> None:
        """After integrating up to ``s1``: the single muscle's fitness there."""
        if self._single_fatigue:
            m0, mu0, mu_inf, lam = self._mu_law
            self._mu = fitness_at(mu0, mu_inf, lam, s1 - m0)

    def free(self, l_ce_m: float, s0: float, s1: float) -> bool:
        """True if no recruited unit makes force over [s0, s1]: the CE is then
        free and follows the MTU, f_SE = 0 (doc/model.md section 4)."""
        return self.eff_f_iso(l_ce_m, s0) == 0.0 and self.eff_f_iso(l_ce_m, s1) == 0.0

    def ce_velocity(self, l_ce_m: float, dl_mt_m: float, t_s: float) -> float:
        """[m/s] d l_CE / dt at CE length ``l_ce_m``, MTU length change
        ``dl_mt_m`` and instant ``t_s``: Eq. 3 inverted at the SE force, with
        Eff.f_iso of that instant (recruitment, fitness, activation)."""
        return self._velocity(l_ce_m, dl_mt_m, self.eff_f_iso(l_ce_m, t_s))

    def _start_mu_law(self, s0: float, s1: float) -> None:
        """Whole-muscle Riener law over [s0, s1] with a held at its midpoint value.

        mu' = (mu_min - mu) a / T_fat + (1 - mu)(1 - a) / T_rec is linear in
        mu: with a held it has the closed form mu_inf + (mu0 - mu_inf) e^(-lam t).
        """
        p = self.params
        s_a, a0, u_d, tau = self._piece
        mid = 0.5 * (s0 + s1)
        a = piece_activation(a0, u_d, tau, mid - s_a)
        a = max(a, 0.0) if a > self._release_level else 0.0
        rate_f, rate_r = 1.0 / p.tau_fatigue_s[0], 1.0 / p.tau_recovery_s[0]
        lam = riener_rate(a, rate_f, rate_r)
        mu_inf = riener_limit(a, p.fatigue_min[0], rate_f, rate_r, lam)
        self._mu_law = (s0, self._mu, mu_inf, lam)

    def _events(self, s0: float, s1: float, a0: float, u_d: float, tau: float,
                m0: int) -> list[tuple[float, int]]:
        """Instants in (s0, s1) where M = floor(N a + 0.5) changes, with the new M.

        From the closed form of a; at most :data:`MAX_EVENTS_PER_PIECE` of them
        (grouped: see there).

        :param m0: [-] M at s0
        """
        n = self.params.n_units
        m1 = recruited_units(activation_at(a0, u_d, tau, s1 - s0), n)
        if m1 == m0:
            return []
        step = 1 if m1 > m0 else -1
        count = abs(m1 - m0)
        if count <= MAX_EVENTS_PER_PIECE:
            targets = range(m0 + step, m1 + step, step)
        else:
            targets = [m0 + step * round(count * (i + 1) / MAX_EVENTS_PER_PIECE)
                       for i in range(MAX_EVENTS_PER_PIECE)]
        out = []
        for m in targets:
            # M reaches m rising when N a + 0.5 >= m; falls to m when N a + 0.5 < m + 1.
            level = (m - 0.5) / n if step > 0 else (m + 0.5) / n
            s = s0 + time_to_reach(a0, u_d, tau, level)
            out.append((min(max(s, s0), s1), m))
        return out

    def plan(self, t0_s: float, t1_s: float) -> list[tuple[float, str, object]]:
        """The recruitment changes of the step [t0, t1]: ``(instant, action, value)``.

        The delayed command and the activation follow closed forms that do not
        depend on the CE length, so every instant at which the recruitment
        changes is known before the step is integrated. An integrator (this
        muscle's :meth:`step`, or a limb's, which integrates several muscles
        and a joint together) integrates up to each instant in turn and calls
        :meth:`apply` there. Consumes the delayed commands due in the step.

        Actions: ``jump`` (a takes the value at once), ``piece`` (a follows
        the closed form from here), ``recruit`` (multi: M units from here),
        ``rise`` and ``release`` (single: a leaves or returns to 0), and
        ``end`` (the activation at t1), always last.
        """
        p = self.params
        actions: list[tuple[float, str, object]] = []
        a, m = self.recruitment, self.n_recruited
        for s0, s1, u_d in self._delay.pieces(t0_s, t1_s):
            tau = self._tau_for(a, u_d) if u_d != a else 0.0
            if tau == 0.0:
                if u_d != a:
                    actions.append((s0, 'jump', u_d))
                    a = u_d
                    m = recruited_units(a, p.n_units) if self._multi else int(a > 0.0)
                actions.append((s0, 'piece', (s0, a, a, 0.0)))
                continue
            actions.append((s0, 'piece', (s0, a, u_d, tau)))
            if self._multi:
                for s_e, m_e in self._events(s0, s1, a, u_d, tau, m):
                    actions.append((s_e, 'recruit', m_e))
                    m = m_e
                a = activation_at(a, u_d, tau, s1 - s0)
                continue
            if a == 0.0:
                actions.append((s0, 'rise', None))
            a1 = activation_at(a, u_d, tau, s1 - s0)
            level = self._release_level
            if u_d < a and u_d < level and a1 < level < a:
                s_rel = s0 + time_to_reach(a, u_d, tau, level)
                actions.append((s_rel, 'release', None))
                if u_d > 0.0:   # rising again towards a command below one unit
                    a_rise = rise_start(u_d, p.tau_act_s)
                    actions.append((s_rel, 'piece', (s_rel, a_rise, u_d, p.tau_act_s)))
                    actions.append((s_rel, 'rise', None))
                    a1 = piece_activation(a_rise, u_d, p.tau_act_s, s1 - s_rel)
                else:
                    actions.append((s_rel, 'piece', (s_rel, 0.0, 0.0, 0.0)))
                    a1 = 0.0
            a = a1
        actions.append((t1_s, 'end', a))
        return actions

    def apply(self, action: str, value: object, t_s: float) -> None:
        """Apply one planned recruitment change at instant ``t_s`` (see :meth:`plan`),
        with the CE length of that instant in ``l_ce_m``."""
        if action == 'piece':
            self._piece = value
        elif action == 'recruit':
            self._pool.update(value, self.l_ce_m / self.params.l_opt_m, t_s)
            self.n_recruited = value
        elif action == 'jump':
            self._set_activation(value, t_s)
        elif action == 'rise':
            self._set_activation_single_rise(t_s)
        elif action == 'release':
            self._set_activation(0.0, t_s)
        else:   # 'end'
            self.recruitment = value
            if not self._multi:
                self.n_recruited = 1 if value > 0.0 else 0

    def _set_activation_single_rise(self, s: float) -> None:
        """Single: a rises from 0 at ``s``: store FL at the CE length of that instant."""
        p = self.params
        self._f_iso_single_n = p.f_iso_max_n * force_length(self.l_ce_m / p.l_opt_m)
        self.n_recruited = 1

    # -- stepping --------------------------------------------------------------------

    def _substeps(self, u: float, dl1: float, dt: float) -> None:
        """One output step of :meth:`step` or :meth:`advance`: :meth:`_advance` in
        n = ceil(dt / 1 ms) equal substeps (:mod:`.substeps`; one at 1 kHz),
        dl_MT ramping linearly across them."""
        n = substeps_for(dt)
        if n == 1:
            self._advance(u, dl1, dt)
            return
        for dl in length_ramp(self.dl_mt_m, dl1, n):
            # Giving u again at a substep's start changes nothing: the delay
            # line keeps a command only where it differs from the last one.
            self._advance(u, dl, dt / n)

    def _advance(self, u: float, dl1: float, dt: float) -> None:
        """One step: command ``u`` given at its start, dl_MT ramping to ``dl1``."""
        t0, dl0 = self.t_s, self.dl_mt_m
        t1 = t0 + dt
        self.give_command(u)
        rate = (dl1 - dl0) / dt
        s = t0
        for instant, action, value in self.plan(t0, t1):
            self._integrate(s, instant, t0, dl0, rate)
            self.apply(action, value, instant)
            s = instant
        self._v_free = rate
        self.dl_mt_m = dl1
        self.t_s = t1
        # A switch due exactly at the step's end acts in this sample already,
        # as a command given at t_k does in the paper's model.
        self.settle_now()
        if self._pool is not None:
            self._pool.advance_to(t1)

    def outputs(self) -> MuscleOutputs:
        """The outputs at the current instant, derived from the state."""
        p = self.params
        l, dl, t = self.l_ce_m, self.dl_mt_m, self.t_s
        self._piece = (t, self.recruitment, self.recruitment, 0.0)
        self._mu_law = (t, self._mu, self._mu, 0.0)
        f_se = series_force(p.k_se_n_per_m, dl, l, p.l_rest_m)
        f_pe = parallel_force(p.k_pe_n_per_m, dl)
        f0 = self.eff_f_iso(l, t)
        v = self._velocity(l, dl, f0) if f0 > 0.0 else self._v_free
        return MuscleOutputs(t, self.recruitment, self.n_recruited, dl, l, v, f_se, f_pe,
                             f_se + f_pe, f0, self.command, self.mean_fitness)

    def run(self, r_start: Sequence[float], dl_mt_end_m: Sequence[float], dt_s: float,
            r_end: Sequence[float] | None = None,
            columns: Sequence[list] | None = None) -> MuscleOutputs:
        """Advance ``len(dl_mt_end_m)`` steps; see :meth:`Muscle.run`.

        ``r_start[k]`` is the command given at the start of step k, ``r_end[k]``
        the one given at its end (the next step's start), before the outputs.
        As :meth:`Muscle.run`, each step is integrated whole (:meth:`step` and
        :func:`.simulate` cut a step longer than 1 ms into substeps first).
        """
        out = None
        for k, dl1 in enumerate(dl_mt_end_m):
            self._advance(r_start[k], dl1, dt_s)
            if r_end is not None and r_end[k] != self.command:
                self.give_command(r_end[k])
            out = self.outputs()
            if columns is not None:
                for column, value in zip(columns, out):
                    column[k] = value
        return out if out is not None else self.outputs()

    def advance(self, dl_mt_end_m: float, dt_s: float) -> None:
        """Integrate one step with the command held; see :meth:`Muscle.advance`."""
        self._substeps(self.command, dl_mt_end_m, dt_s)

    def step(self, recruitment: float, dl_mt_m: float, dt_s: float) -> MuscleOutputs:
        """Advance one step with command u = ``recruitment`` given at its start.

        :param recruitment: [-] recruitment command u in [0, 1]
        :param dl_mt_m: [m] MTU length change at the end of the step (dl_MT)
        :param dt_s: [s] step length, > 0
        :return: the outputs at the end of the step
        :raises ValueError: on a NaN, infinite or out-of-range input; the state
            is unchanged
        """
        u, dl = check_recruitment(recruitment), check_dl_mt(dl_mt_m)
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
        self._substeps(u, dl, dt_s)
        return self.outputs()
