"""The CE's velocity, relaxation rate and quasi-static force over the flat state:
:mod:`.equations`' scalar laws with a muscle's constants read from ``F`` and
``I`` (shared by :mod:`.kernels` and :mod:`.ding_kernels`)."""
from __future__ import annotations

from ..equations import fes_velocity, quasi_static_force, relaxation_rate
from .state import (H_FP, H_IP, I_RELATIVE, P_A, P_A_ECC, P_B, P_B_ECC, P_F_ISO_MAX, P_K_SE,
                    P_L_REST, hdr)


def velocity(F, I, i, l, dl, f0):
    """[m/s] d l_CE / dt at F0 = ``f0``."""
    fp, ip = hdr(I, i, H_FP), hdr(I, i, H_IP)
    return fes_velocity(l, dl, f0, F[fp + P_K_SE], F[fp + P_L_REST], F[fp + P_A], F[fp + P_B],
                        F[fp + P_A_ECC], F[fp + P_B_ECC], F[fp + P_F_ISO_MAX],
                        I[ip + I_RELATIVE] != 0)


def rate_at(F, I, i, l, dl, f0):
    """[1/s] the CE's relaxation rate at F0 = ``f0``."""
    fp, ip = hdr(I, i, H_FP), hdr(I, i, H_IP)
    return relaxation_rate(l, dl, f0, F[fp + P_K_SE], F[fp + P_L_REST], F[fp + P_A],
                           F[fp + P_B], F[fp + P_A_ECC], F[fp + P_B_ECC], F[fp + P_F_ISO_MAX],
                           I[ip + I_RELATIVE] != 0)


def quasi_force(F, I, i, v, f0):
    """[N] the CE's force moving at ``v`` with F0 = ``f0``."""
    fp, ip = hdr(I, i, H_FP), hdr(I, i, H_IP)
    return quasi_static_force(v, f0, F[fp + P_A], F[fp + P_B],
                              F[fp + P_A_ECC], F[fp + P_B_ECC], F[fp + P_F_ISO_MAX],
                              I[ip + I_RELATIVE] != 0)
