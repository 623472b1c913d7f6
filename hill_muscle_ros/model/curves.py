"""Force-length and force-velocity curves of the Hill-type model, and the springs.

Every function here is pure and scalar (plain ``float`` in, ``float`` out) so
that the integrator's hot loop can call it without NumPy overhead. Units are SI
throughout (doc/model.md sections 1-3).
"""
from __future__ import annotations

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
