"""The model's equations, each written once as a plain scalar function.

Force-length (Eq. 1) and force-velocity (Eq. 3) and its inverse, the springs,
the activation's closed form, whole-muscle and per-unit fatigue, the CE with
relative Hill constants, the classical RK4 update and its stiffness bound, and
the joint's equation of motion. Every engine calls these: the muscle, the
batch and the limb, compiled by numba (:mod:`.engine`) or, with
``HILL_MUSCLE_ENGINE=python``, run as they are. Every function is pure and
scalar (plain ``float`` in, ``float`` out) so that numba inlines it and Python
calls it without NumPy overhead. Units are SI throughout (doc/model.md).
"""
from __future__ import annotations

import math

#: Coefficients of the normalised force-length parabola, Eq. (1) of the paper:
#: FL(x) = FL_A x^2 + FL_B x + FL_C, with x = length / l_opt.
FL_A = -2.777
FL_B = 5.554
FL_C = -1.777

#: Eccentric force plateau as a multiple of the isometric force (Eq. 3).
ECC_PLATEAU = 1.5


def force_length(x: float) -> float:
    """Normalised force-length relation FL(x), clipped at zero.

    Implements Eq. (1) of the paper. It peaks at FL(1) = 1 and is zero outside
    about 0.4 < x < 1.6.

    :param x: [-] length normalised by the optimal length (l / l_opt)
    :return: [-] normalised isometric force FL(x), in [0, 1]
    """
    fl = (FL_A * x + FL_B) * x + FL_C
    return fl if fl > 0.0 else 0.0


def force_velocity(v_ce: float, f0: float, a: float, b: float,
                   a_ecc: float, b_ecc: float) -> float:
    """CE force for a given CE velocity (the Hill force-velocity relation).

    Implements Eq. (3) of the paper with the sign choice of doc/model.md section 3:
    the eccentric branch is ``1.5 F0 - 0.5 (F0 b' - a' v) / (b' + v)``, which is
    continuous at ``v = F0 b' / a'`` where it reaches ``1.5 F0``.

    :param v_ce: [m/s] CE velocity (v_CE), negative when shortening
    :param f0: [N] effective isometric force (Eff.f_iso, F0)
    :param a: [N] concentric Hill constant (a)
    :param b: [m/s] concentric Hill constant (b)
    :param a_ecc: [N] eccentric constant (a')
    :param b_ecc: [m/s] eccentric constant (b')
    :return: [N] CE force (f_CE)
    """
    if v_ce <= 0.0:
        if v_ce <= -f0 * b / a:
            return 0.0
        return (f0 * b + a * v_ce) / (b - v_ce)
    if v_ce > f0 * b_ecc / a_ecc:
        return ECC_PLATEAU * f0
    return ECC_PLATEAU * f0 - 0.5 * (f0 * b_ecc - a_ecc * v_ce) / (b_ecc + v_ce)


def force_velocity_inverse(f_ce: float, f0: float, a: float, b: float,
                           a_ecc: float, b_ecc: float) -> float:
    """CE velocity that produces a given CE force: the inverse of Eq. (3).

    Continuous and non-decreasing in ``f_ce`` (doc/model.md section 3). With
    ``f0 = 0`` the CE offers no resistance and this function is not meaningful;
    the muscle handles that case itself (doc/model.md section 4).

    :param f_ce: [N] CE force, equal to the SE force (f_SE) in the massless MTU
    :param f0: [N] effective isometric force (Eff.f_iso, F0), > 0
    :param a: [N] concentric Hill constant (a)
    :param b: [m/s] concentric Hill constant (b)
    :param a_ecc: [N] eccentric constant (a')
    :param b_ecc: [m/s] eccentric constant (b')
    :return: [m/s] CE velocity (v_CE), negative when shortening
    """
    # One division for all four branches (numerator / denominator), the same
    # numbers as dividing in each: compiled for many muscles at once
    # (model/kernels.py), every branch is evaluated, and divisions dominate.
    if f_ce <= 0.0:
        num, den = -f0 * b, a
    elif f_ce <= f0:
        num, den = b * (f_ce - f0), f_ce + a
    elif f_ce < ECC_PLATEAU * f0:
        num, den = b_ecc * (2.0 * f_ce - 2.0 * f0), 3.0 * f0 - 2.0 * f_ce + a_ecc
    else:
        num, den = f0 * b_ecc, a_ecc
    return num / den


def isometric_force_for(f_ce: float, v_ce: float, a: float, b: float,
                        a_ecc: float, b_ecc: float) -> float:
    """Effective isometric force at which the CE gives ``f_ce`` at ``v_ce``:
    Eq. (3) solved for F0 instead of for the force.

    For a fixed velocity each branch of Eq. (3) is linear in F0, so this is
    exact. A controller uses it to ask how much muscle it must recruit to hold
    a force while the muscle is being moved (inverse dynamics).

    Lengthening is bounded: at force ``f_ce`` the CE lengthens at most at
    ``f_ce b' / (1.5 a')``, reached at ``F0 = f_ce / 1.5`` (the start of the
    eccentric plateau); a smaller F0 is slower (``F0 b' / a'``) and a larger
    one too. If ``v_ce`` is above that bound no F0 gives it and this returns
    ``f_ce / 1.5``, the F0 that comes closest.

    :param f_ce: [N] CE force wanted (f_CE = f_SE), >= 0
    :param v_ce: [m/s] CE velocity (v_CE), negative when shortening
    :param a: [N] concentric Hill constant (a)
    :param b: [m/s] concentric Hill constant (b)
    :param a_ecc: [N] eccentric constant (a')
    :param b_ecc: [m/s] eccentric constant (b')
    :return: [N] effective isometric force (Eff.f_iso, F0), >= 0
    """
    if f_ce <= 0.0:
        return 0.0
    if v_ce <= 0.0:
        # (F0 b + a v) / (b - v) = f  <=>  F0 = (f (b - v) - a v) / b
        return (f_ce * (b - v_ce) - a * v_ce) / b
    # 1.5 F0 - 0.5 (F0 b' - a' v) / (b' + v) = f, linear in F0
    share = b_ecc / (b_ecc + v_ce)
    f0 = (f_ce - 0.5 * a_ecc * v_ce / (b_ecc + v_ce)) / (ECC_PLATEAU - 0.5 * share)
    if v_ce > f0 * b_ecc / a_ecc:
        return f_ce / ECC_PLATEAU   # faster than any F0 allows: the fastest one
    return f0


def series_force(k_se: float, dl_mt: float, l_ce: float, l_rest: float) -> float:
    """Tendon (series elastic) force; the spring pulls but never pushes.

    :param k_se: [N/m] SE stiffness (k_SE)
    :param dl_mt: [m] MTU length change from rest (dl_MT), positive = stretch
    :param l_ce: [m] CE length (l_CE)
    :param l_rest: [m] CE length at rest (l_rest)
    :return: [N] SE force (f_SE)
    """
    stretch = dl_mt - (l_ce - l_rest)
    return k_se * stretch if stretch > 0.0 else 0.0


def parallel_force(k_pe: float, dl_mt: float) -> float:
    """Parallel elastic force; the PE spans the whole MTU and never pushes.

    :param k_pe: [N/m] PE stiffness (k_PE)
    :param dl_mt: [m] MTU length change from rest (dl_MT)
    :return: [N] PE force (f_PE)
    """
    return k_pe * dl_mt if dl_mt > 0.0 else 0.0


# -- the activation (doc/model.md 7.2) ------------------------------------------------
# First order, in closed form on each piece of constant delayed command.

def activation_at(a0: float, u_d: float, tau_s: float, elapsed_s: float) -> float:
    """Closed form of the first-order activation with a constant input.

    :param a0: [-] activation at the start of the piece
    :param u_d: [-] delayed command, constant over the piece
    :param tau_s: [s] time constant in force on the piece, > 0
    :param elapsed_s: [s] time since the start of the piece
    :return: [-] a(t0 + elapsed)
    """
    return u_d + (a0 - u_d) * math.exp(-elapsed_s / tau_s)


def time_to_reach(a0: float, u_d: float, tau_s: float, level: float) -> float:
    """[s] time after the piece start at which the activation reaches ``level``.

    The inverse of :func:`activation_at`; ``level`` must lie strictly between
    ``a0`` and ``u_d`` (a reaches u_d only asymptotically).
    """
    return tau_s * math.log((a0 - u_d) / (level - u_d))


# -- the FES muscle (doc/model.md 4 and 7) --------------------------------------------
# The activation on a piece, whole-muscle fatigue (Riener), the CE with relative
# Hill constants, the RK4 update and its stiffness bound.

#: Most recruitment events resolved one by one within a piece of a step. With
#: more (a fast activation of many units), the events are taken in this many
#: groups of equal unit counts, each group recruited at its last unit's
#: instant: the force is then held for 1/64 of the piece's recruitment change
#: instead of all of it, about 1/64 of the error of holding R over the step.
MAX_EVENTS_PER_PIECE = 64


#: Largest h lambda per RK4 step, lambda the bound on the CE's relaxation rate
#: (:func:`relaxation_rate`). Classical RK4 is stable on the real axis
#: up to 2.785, but a step of h lambda near 1 across a kink of Eq. 3 (the
#: tendon force leaving the eccentric plateau) errs by over 1 N with a stiff
#: tendon (limb reference, k_SE = 300 kN/m); 0.5 keeps that within 0.15 N. The
#: paper's muscle (lambda <= 330 /s) still takes one step per millisecond.
RK4_MAX_H_LAMBDA = 0.5


#: Most RK4 steps one interval is cut into. Only a CE whose constants vanish
#: with F0 (``fv_scaling: relative`` as the last units leave) gets near it.
MAX_SUBSTEPS = 1000


#: [1/s] A CE whose relaxation rate is at least this moves with its MTU at the
#: force Eq. 3 gives that velocity (:func:`quasi_static_force`) instead of being
#: integrated: it relaxes within 1 / 1e5 s = 10 us, a hundredth of the 1 ms
#: step, and lags behind that force by about the force's rate over the
#: relaxation rate (f' / lambda: 0.01 N at 1000 N/s). Only ``fv_scaling:
#: relative`` with few units recruited gets there (the rate grows as 1 / F0:
#: the knee preset's quadriceps below about 2 N of F0, isometric). Below it RK4
#: takes up to 200 steps a millisecond; above it, it took up to MAX_SUBSTEPS.
#: Our choice, measured against the fine-step references (doc/model.md 7.6):
#: the stimulated-quadriceps preset released while stretched errs 0.49, 0.075,
#: 0.012 N at 2e4, 5e4, 1e5 /s (RK4 throughout: 0.009 N; the tests ask 0.05).
QUASI_STATIC_RATE_PER_S = 1.0e5


def piece_activation(a0: float, u_d: float, tau_s: float, elapsed_s: float) -> float:
    """[-] the activation ``elapsed_s`` into a piece of constant delayed command:
    the closed form while it moves (tau > 0, a0 != u_d), else a0 held.

    :param a0: [-] activation at the start of the piece
    :param u_d: [-] delayed command over the piece
    :param tau_s: [s] time constant in force (0: the activation jumped)
    :param elapsed_s: [s] time since the start of the piece
    """
    return activation_at(a0, u_d, tau_s, elapsed_s) if (tau_s > 0.0 and a0 != u_d) else a0


def rise_start(u_d: float, tau_act_s: float) -> float:
    """[-] the activation of a single muscle rising again at the instant it was
    released (doc/model.md section 7.2): 0, from where it follows the closed form
    towards ``u_d``; with instantaneous activation (tau_act = 0) the command itself.

    :param u_d: [-] delayed command it rises towards, > 0
    :param tau_act_s: [s] activation time constant (0: instantaneous)
    """
    return 0.0 if tau_act_s > 0.0 else u_d


def riener_rate(a: float, rate_fat: float, rate_rec: float) -> float:
    """[1/s] lambda of Riener's fitness law with the activation ``a`` held:
    mu' = (mu_min - mu) a / T_fat + (1 - mu)(1 - a) / T_rec = lambda (mu_inf - mu).

    :param rate_fat: [1/s] 1 / T_fat
    :param rate_rec: [1/s] 1 / T_rec
    """
    return a * rate_fat + (1.0 - a) * rate_rec


def riener_limit(a: float, mu_min: float, rate_fat: float, rate_rec: float,
                 lam: float) -> float:
    """[-] mu_inf of Riener's law with ``a`` held (see :func:`riener_rate`)."""
    return (mu_min * a * rate_fat + (1.0 - a) * rate_rec) / lam


def fitness_at(mu0: float, mu_inf: float, lam: float, elapsed_s: float) -> float:
    """[-] mu ``elapsed_s`` after it was ``mu0``, tending to ``mu_inf`` at rate ``lam``."""
    return mu_inf + (mu0 - mu_inf) * math.exp(-lam * elapsed_s)


def fes_velocity(l_ce_m: float, dl_mt_m: float, f0_n: float, k_se: float, l_rest_m: float,
                 a: float, b: float, a_ecc: float, b_ecc: float, f_iso_max_n: float,
                 relative: bool) -> float:
    """[m/s] FV_inv(f_SE, F0), Eq. 3 inverted; ``relative`` scales a and a' with F0.

    :param l_ce_m: [m] CE length (l_CE)
    :param dl_mt_m: [m] MTU length change (dl_MT)
    :param f0_n: [N] Eff.f_iso (F0)
    :param k_se: [N/m] SE stiffness; a, b, a', b' the Hill constants
    :param l_rest_m: [m] CE rest length (l_rest)
    :param f_iso_max_n: [N] f_iso_max, the F0 at which relative constants are a, a'
    :param relative: True for ``fv_scaling: relative``
    """
    f_se = series_force(k_se, dl_mt_m, l_ce_m, l_rest_m)
    if relative:
        if f0_n <= 0.0:
            # The limits of the fastest speeds as F0 -> 0, which no longer
            # depend on F0: b f_iso_max / a shortening, b' f_iso_max / a' lengthening.
            if f_se <= 0.0:
                return -b * f_iso_max_n / a
            return b_ecc * f_iso_max_n / a_ecc
        share = f0_n / f_iso_max_n
        a, a_ecc = a * share, a_ecc * share
    return force_velocity_inverse(f_se, f0_n, a, b, a_ecc, b_ecc)


def relaxation_rate(l_ce_m: float, dl_mt_m: float, f0_n: float, k_se: float,
                    l_rest_m: float, a: float, b: float, a_ecc: float, b_ecc: float,
                    f_iso_max_n: float, relative: bool) -> float:
    """[1/s] |d v_CE / d l_CE| at F0 = ``f0_n``: see :func:`relaxation_rate`
    (the arguments as :func:`fes_velocity`'s)."""
    if f0_n <= 0.0:
        return 0.0
    if relative:
        share = f0_n / f_iso_max_n
        a, a_ecc = a * share, a_ecc * share
    f = k_se * (dl_mt_m - (l_ce_m - l_rest_m))
    if f <= f0_n:
        f = f if f > 0.0 else 0.0
        slope = b * (a + f0_n) / ((f + a) * (f + a))
    else:
        f = f if f < ECC_PLATEAU * f0_n else ECC_PLATEAU * f0_n
        slope = 2.0 * b_ecc * (f0_n + a_ecc) / ((3.0 * f0_n - 2.0 * f + a_ecc) ** 2)
    return k_se * slope


def quasi_static_force(v_ce_m_per_s: float, f0_n: float, a: float, b: float, a_ecc: float,
                       b_ecc: float, f_iso_max_n: float, relative: bool) -> float:
    """[N] the force of a CE moving at ``v_ce_m_per_s``: Eq. 3, FV(v_CE, F0), with
    ``relative`` scaling a and a' with F0 (the inverse of :func:`fes_velocity`).
    The force of a quasi-static CE (:data:`QUASI_STATIC_RATE_PER_S`), whose SE
    then has this force and whose velocity is its MTU's.

    :param v_ce_m_per_s: [m/s] CE velocity (v_CE), negative when shortening
    :param f0_n: [N] Eff.f_iso (F0); 0 gives 0
    """
    if f0_n <= 0.0:
        return 0.0
    if relative:
        share = f0_n / f_iso_max_n
        a, a_ecc = a * share, a_ecc * share
    return force_velocity(v_ce_m_per_s, f0_n, a, b, a_ecc, b_ecc)


def rk4_update(y: float, h_s: float, k1: float, k2: float, k3: float, k4: float) -> float:
    """y + h (k1 + 2 k2 + 2 k3 + k4) / 6: classical RK4's step from its four stages."""
    return y + h_s / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def substep_count(h_s: float, rate: float) -> int:
    """RK4 steps for an interval of ``h_s`` at relaxation rate ``rate`` [1/s]:
    h lambda at most :data:`RK4_MAX_H_LAMBDA` each, at most :data:`MAX_SUBSTEPS`."""
    n = h_s * rate / RK4_MAX_H_LAMBDA
    return 1 if n <= 1.0 else min(math.ceil(n), MAX_SUBSTEPS)


# -- per-unit fatigue on the pool's common clocks (doc/model.md 7.3) -----------------

def recruited_excess(dn, h, mu_min, d):
    """(mu - mu_min) / D(t) of units recruited now, from their resting deficit.

    :param dn: [-] stored deficit (1 - mu) / H(t) of the resting units
    :param h: [-] recovery clock H(t) now
    :param mu_min: [-] fitness floor mu_min
    :param d: [-] fatigue clock D(t) now
    """
    return ((1.0 - dn * h) - mu_min) / d


def resting_deficit(exn, d, mu_min, h):
    """(1 - mu) / H(t) of units released now, from their stored excess
    (the arguments as :func:`recruited_excess`'s)."""
    return (1.0 - (mu_min + exn * d)) / h


def moment_force(f_max: float, a2: float, a1: float, a0: float, n: float, c1: float,
                 c2: float) -> float:
    """[N] f_max (a2 sum c^2 + a1 sum c + a0 n): the FL parabola a2 c^2 + a1 c + a0
    (in the unit scale c, at a given CE length) summed over moments, each
    moment already weighted by the units' fitness."""
    return f_max * (a2 * c2 + a1 * c1 + a0 * n)


# -- the joint (doc/model.md 9) ----------------------------------------------------------

def mtu_length_change(s_r: float, theta_rad: float, reference_angle_rad: float) -> float:
    """[m] dl_MT = -s r (theta - theta_ref) of a muscle with ``s_r`` = s r [m]."""
    return -s_r * (theta_rad - reference_angle_rad)


def joint_acceleration(muscle_torque_n_m: float, theta_rad: float, omega_rad_per_s: float,
                       external_torque_n_m: float, inertia_kg_m2: float, mass_kg: float,
                       gravity_m_per_s2: float, com_distance_m: float,
                       stiffness_n_m_per_rad: float, equilibrium_rad: float,
                       damping_n_m_s_per_rad: float) -> float:
    """[rad/s^2] domega/dt = (sum s r F - m g l_c sin theta - K (theta - theta_eq)
    - B omega + tau_ext) / J (the joint's parameters as :class:`JointParams`')."""
    return joint_acceleration_sin(muscle_torque_n_m, theta_rad, math.sin(theta_rad),
                                  omega_rad_per_s, external_torque_n_m, inertia_kg_m2, mass_kg,
                                  gravity_m_per_s2, com_distance_m, stiffness_n_m_per_rad,
                                  equilibrium_rad, damping_n_m_s_per_rad)


def joint_acceleration_sin(muscle_torque_n_m: float, theta_rad: float, sin_theta: float,
                           omega_rad_per_s: float, external_torque_n_m: float,
                           inertia_kg_m2: float, mass_kg: float, gravity_m_per_s2: float,
                           com_distance_m: float, stiffness_n_m_per_rad: float,
                           equilibrium_rad: float, damping_n_m_s_per_rad: float) -> float:
    """[rad/s^2] :func:`joint_acceleration` given ``sin_theta`` = sin theta."""
    return (muscle_torque_n_m - mass_kg * gravity_m_per_s2 * com_distance_m * sin_theta
            - stiffness_n_m_per_rad * (theta_rad - equilibrium_rad)
            - damping_n_m_s_per_rad * omega_rad_per_s + external_torque_n_m) / inertia_kg_m2


#: [rad] Largest |d| for which :func:`sine_near` takes sin and cos of d from their
#: series. The first terms left out, d^9 / 9! and d^10 / 10!, are 1.4e-21 and
#: 2.8e-24 at 0.02 rad, far below a double's rounding; an RK4 stage of 1 ms
#: moves the joint by 0.02 rad only at 20 rad/s (40 at the half-step stages).
SINE_SERIES_MAX_RAD = 0.02


def sine_near(sin_a: float, cos_a: float, d_rad: float) -> float:
    """[-] sin(theta_a + d) from sin theta_a and cos theta_a: the angle-addition
    formula with the series of sin d and cos d, for |d| <= :data:`SINE_SERIES_MAX_RAD`
    (to rounding).

    Why: the compiled limb's RK4 asks the gravity torque at four stage angles
    a few milliradians apart; libm's sin there cost 9 % of the knee extension's
    run, and each call makes the compiled stage save and reload its registers.

    :param d_rad: [rad] how far theta is from theta_a (d)
    """
    d2 = d_rad * d_rad
    # Horner's forms of sum (-1)^n d^2n / (2n)! and sum (-1)^n d^(2n+1) / (2n+1)!.
    cos_d = 1.0 + d2 * (-1.0 / 2.0 + d2 * (1.0 / 24.0 + d2 * (-1.0 / 720.0
                                                                 + d2 * (1.0 / 40320.0))))
    sin_d = d_rad * (1.0 + d2 * (-1.0 / 6.0 + d2 * (1.0 / 120.0 + d2 * (-1.0 / 5040.0))))
    return sin_a * cos_d + cos_a * sin_d


# -- the strength-duration law of a pulse (doc/model.md 10) -------------------------------

#: [s] Chronaxie c of the stimulated motor axons: 459 us, the strength-duration
#: time constant of human motor axons (compound muscle action potentials at 30 %
#: of maximum, 20 volunteers; 459 +/- 126 us), Mogyoros, Kiernan & Burke 1996,
#: *Brain* 119:439-447, whose data Weiss's charge law Q = r (PW + c) fits, the
#: law of :func:`threshold_current`, so that the time constant is c. Measured
#: at the median nerve: no quadriceps-specific value was found (doc/model.md
#: section 10); surface FES of the quadriceps excites the same kind of axon.
DEFAULT_CHRONAXIE_S = 459e-6
#: [A] Reference current I_ref, at which the recruitment curve in pulse width
#: holds: 40 mA, the constant amplitude at which vastus lateralis and medialis
#: were stimulated with their pulse width modulated in a knee-extension study
#: (IFESS 2016, "Comparison of proximally versus distally placed spatially
#: distributed sequential stimulation electrodes in a dynamic knee extension
#: task"; doc/model.md section 10).
DEFAULT_CURRENT_REF_A = 0.040


def threshold_current(pulse_width_s: float, rheobase_a: float, chronaxie_s: float) -> float:
    """[A] Current that just excites a unit of rheobase r with a pulse of width PW:
    the hyperbolic strength-duration law I_th = r (1 + c / PW) (Weiss, Lapicque;
    Geddes 2004 writes it I = b (1 + c / d)). It is r at an infinite width and
    2 r at PW = c (the chronaxie's definition); +inf at PW = 0.

    :param pulse_width_s: [s] pulse width (PW), >= 0
    :param rheobase_a: [A] the unit's rheobase (r), >= 0
    :param chronaxie_s: [s] chronaxie (c), > 0
    """
    if pulse_width_s <= 0.0:
        return math.inf
    return rheobase_a * (pulse_width_s + chronaxie_s) / pulse_width_s


def equivalent_pulse_width(pulse_width_s: float, current_a: float, current_ref_a: float,
                           chronaxie_s: float) -> float:
    """[s] The width PW_eq that recruits, at the reference current, the units a
    pulse (I, PW) recruits.

    A unit of rheobase r is excited by (I, PW) if I PW / (PW + c) >= r
    (:func:`threshold_current` solved for r), so (I, PW) excites every unit
    with r <= k = I PW / (PW + c). At I_ref the width that reaches the same k
    is PW_eq = c k / (I_ref - k) for k < I_ref; for k >= I_ref no width at
    I_ref does, and PW_eq = +inf (every unit the curve knows is recruited).
    Written c I PW / (c I_ref + (I_ref - I) PW), the same fraction over PW + c,
    so that I = I_ref gives PW exactly. I = 0 or PW = 0 gives 0 (no pulse).

    :param pulse_width_s: [s] pulse width (PW), >= 0
    :param current_a: [A] pulse current (I), >= 0
    :param current_ref_a: [A] reference current (I_ref), > 0
    :param chronaxie_s: [s] chronaxie (c), > 0
    :return: [s] PW_eq, in [0, +inf]
    """
    if pulse_width_s <= 0.0 or current_a <= 0.0:
        return 0.0
    denominator = chronaxie_s * current_ref_a + (current_ref_a - current_a) * pulse_width_s
    if denominator <= 0.0:
        return math.inf
    return pulse_width_s * ((chronaxie_s * current_a) / denominator)


# -- Ding et al. 2003's pulse-resolved activation, normalised (doc/model.md section 10) --


def ding_pulse_weight(since_last_s: float, r0: float, tau_c_s: float) -> float:
    """[-] R_i of a pulse ``since_last_s`` after the channel's previous one:
    1 + (R0 - 1) exp(-(t_i - t_(i-1)) / tau_c); R_1 = 1 for the first (``since_last_s``
    = +inf). Ding et al. 2003's enhancement of CN by a closely following pulse.

    :param r0: [-] R0 = Km + r0_offset
    :param tau_c_s: [s] tau_c
    """
    return 1.0 + (r0 - 1.0) * math.exp(-since_last_s / tau_c_s)


def ding_cn_at(cn0: float, sum0: float, tau_c_s: float, elapsed_s: float) -> float:
    """[-] CN ``elapsed_s`` after it was ``cn0`` with the pulse sum ``sum0``, no pulse
    between: CN' = (S - CN) / tau_c with S = sum0 exp(-t / tau_c), whose exact
    solution is (cn0 + sum0 t / tau_c) exp(-t / tau_c) (Ding et al. 2003's CN law).
    """
    return (cn0 + sum0 * elapsed_s / tau_c_s) * math.exp(-elapsed_s / tau_c_s)


def ding_rate(cn: float, a: float, km: float, tau1_s: float, tau2_s: float) -> float:
    """[1/s] a' = x / (tau1 + tau2) - a / (tau1 + tau2 x), x = CN / (Km + CN):
    Ding et al. 2003's force law F' = A x - F / (tau1 + tau2 x) divided by
    A (tau1 + tau2), the force at infinite frequency, so 0 <= a < 1 and A drops out.
    """
    x = cn / (km + cn)
    return x / (tau1_s + tau2_s) - a / (tau1_s + tau2_s * x)
