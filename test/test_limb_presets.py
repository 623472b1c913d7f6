"""The limb presets, ``config/knee.yaml`` and ``config/ankle.yaml``.

Each loads with the package's plant loader; every derived value is recomputed
here from the numbers its comments cite (Winter's table, the pendulum test,
Rajagopal et al. 2016, Riener and Edrich 1999, OpenSim's rules); and each
behaves plausibly:

- the seated knee extends from hanging to horizontal at a pulse width inside
  the stimulator's range, near the static estimate written here;
- the relaxed knee released from 30 deg swings with the period and the decay
  that the pendulum test's stiffness and damping give;
- the drop foot rests plantarflexed, and stimulation of the tibialis anterior
  lifts it to the neutral ankle at a pulse width inside the range.
"""
import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from hill_muscle_ros import resources
from hill_muscle_ros.model.limb import LimbPlant, LimbProtocol, simulate_limb
from hill_muscle_ros.params_file import load_muscle_params, load_plant

KNEE = resources.config_dir() / 'knee.yaml'
ANKLE = resources.config_dir() / 'ankle.yaml'
FES_QUADRICEPS = resources.config_dir() / 'fes_quadriceps.yaml'

# -- Sources, as the presets cite them ---------------------------------------------
#: Winter's table for a 70 kg, 1.75 m adult: shank + foot mass share, centre of
#: mass and radius of gyration about the knee as shares of the leg length, and
#: the leg length as a share of height.
BODY_MASS_KG, HEIGHT_M = 70.0, 1.75
WINTER_MASS_SHARE, WINTER_COM_SHARE, WINTER_GYRATION_SHARE = 0.061, 0.606, 0.735
WINTER_LEG_SHARE = 0.246
#: Relaxed paraplegic knee in the pendulum test: [N m/rad], [N m s/rad].
PENDULUM_K, PENDULUM_B = 15.3, 0.41
#: [m] patellar tendon moment arm at 0 / 20 / 40 / 60 deg of flexion.
PATELLAR_ARMS_M = (0.0426, 0.0399, 0.0377, 0.0362)
#: [deg] knee flexion of the greatest knee-extension torque (Sosnoff et al. 2010).
OPTIMAL_FLEXION_DEG = 60.0
#: Rajagopal et al. 2016 (Rajagopal2016.osim): [N] maximal force, [m] optimal fibre
#: length, [m] tendon slack length.
RAJAGOPAL_QUADRICEPS_N = (2191.74, 1697.36, 5148.77, 2747.82)
RAJAGOPAL_HAMSTRINGS = {          # biceps femoris long, short head, semimembranosus,
    'bflh': (1313.18, 0.0976, 0.3252),   # semitendinosus
    'bfsh': (557.11, 0.1103, 0.1058),
    'semimem': (2200.99, 0.0690, 0.3476),
    'semiten': (591.30, 0.1930, 0.2472),
}
RAJAGOPAL_TIBIALIS_ANTERIOR = (1227.45, 0.0683, 0.2405)
#: [m] typical knee moment arms of the hamstrings (midpoints of a textbook table's ranges).
HAMSTRING_ARMS_M = {'bflh': 0.020, 'bfsh': 0.020, 'semimem': 0.030, 'semiten': 0.0475}
#: [N] the stimulated quadriceps of config/fes_quadriceps.yaml.
FES_QUADRICEPS_N = 1500.0
#: OpenSim: tendon strain at maximal force, Hill constant a / F_max, maximal
#: shortening speed [l_opt/s]; the paper's eccentric ratio b' / b.
OPENSIM_TENDON_STRAIN, OPENSIM_HILL_A, OPENSIM_V_MAX = 0.049, 0.25, 10.0
PAPER_ECC_B_RATIO = 0.75
#: The parallel springs are this share of the joint stiffness through the arm.
PE_SHARE_OF_K = 0.01
#: The drop-foot model (Benoussaad-type, public code): foot mass [kg], centre of
#: mass [m], inertia [kg m^2], viscosity [N m s/rad], TA arm [m], force [N],
#: activation and deactivation [s].
FOOT = {'mass_kg': 1.0275, 'com_distance_m': 0.1145, 'inertia_kg_m2': 0.0197,
        'damping_n_m_s_per_rad': 0.82}
TA_ARM_M, TA_FORCE_N, TA_TAU_S = 0.037, 600.0, (0.010, 0.040)


def riener_edrich_ankle_n_m(dorsiflexion_deg: float, knee_flexion_deg: float = 0.0) -> float:
    """[N m] Riener and Edrich 1999's passive ankle moment, positive in dorsiflexion."""
    return (math.exp(-7.9763 - 0.1949 * dorsiflexion_deg + 0.0008 * knee_flexion_deg)
            - math.exp(2.1016 + 0.0843 * dorsiflexion_deg - 0.0176 * knee_flexion_deg)
            + 1.792)


def fl(x: float) -> float:
    """The paper's force-length relation (Eq. 1), written here."""
    return max(0.0, -2.777 * x * x + 5.554 * x - 1.777)


def ding_pulse_width_s(u: float, threshold_s: float, scale_s: float) -> float:
    """[s] The pulse width whose exponential recruitment curve gives command u."""
    return threshold_s - scale_s * math.log(1.0 - u)


# -- Fixtures ------------------------------------------------------------------------

@pytest.fixture(scope='module')
def knee():
    plant, node = load_plant(KNEE)
    return plant


@pytest.fixture(scope='module')
def ankle():
    plant, node = load_plant(ANKLE)
    return plant


def muscle(plant: LimbPlant, name: str):
    return next(m for m in plant.muscles if m.name == name)


def passive_torque(plant: LimbPlant, theta: float) -> float:
    """[N m] gravity, joint spring and the muscles' parallel springs at rest (no
    stimulation, CEs free): the static torque balance, written here."""
    j = plant.joint
    torque = (-j.mass_kg * j.gravity_m_per_s2 * j.com_distance_m * math.sin(theta)
              - j.stiffness_n_m_per_rad * (theta - j.equilibrium_rad))
    for m in plant.muscles:
        sign = 1.0 if m.action == 'extensor' else -1.0
        dl = -sign * m.moment_arm_m * (theta - m.reference_angle_rad)
        torque += sign * m.moment_arm_m * m.params.k_pe_n_per_m * max(dl, 0.0)
    return torque


def rest_angle(plant: LimbPlant) -> float:
    """[rad] where the passive torque balances, found with brentq."""
    return brentq(lambda x: passive_torque(plant, x), -math.pi / 2, math.pi)


def train(name: str, muscle_name: str, pulse_width_s: float, on_s: float,
          duration_s: float) -> LimbProtocol:
    """A pulse width from ``on_s`` to the end, nothing before."""
    return LimbProtocol.from_mapping({
        'name': name, 'duration_s': duration_s,
        'muscles': {muscle_name: {'pulse_width_s': [[on_s, 0.0], [on_s, pulse_width_s]]}}})


def smallest_pulse_width_reaching(plant: LimbPlant, muscle_name: str, target_rad: float,
                                  on_s: float, duration_s: float) -> float:
    """[s] The smallest constant pulse width whose train takes the joint to
    ``target_rad``, by bracketed root finding (brentq) on the peak angle of
    simulate_limb runs, to 1 us."""
    p = muscle(plant, muscle_name).params

    def margin(pw: float) -> float:
        r = simulate_limb(plant, train('reach', muscle_name, pw, on_s, duration_s))
        return float(np.max(r['theta_rad'])) - target_rad

    assert margin(p.pw_threshold_s) < 0.0 < margin(p.pw_max_s)
    return brentq(margin, p.pw_threshold_s, p.pw_max_s, xtol=1e-6)


def static_pulse_width(plant: LimbPlant, muscle_name: str, target_rad: float) -> float:
    """[s] The pulse width whose fresh units, all recruited at the rest length
    (``initial`` memory), hold ``target_rad`` against the passive torque: a
    static estimate from the torque balance, the FL relation and the curve."""
    m = muscle(plant, muscle_name)
    p = m.params
    torque = -passive_torque(plant, target_rad)
    rest = rest_angle(plant)
    x_recruited = (p.l_rest_m - m.moment_arm_m * (rest - m.reference_angle_rad)) / p.l_opt_m
    u = torque / m.moment_arm_m / (p.f_iso_max_n * fl(x_recruited))
    return ding_pulse_width_s(u, p.pw_threshold_s, p.pw_scale_s)


# -- The knee: values from their sources ---------------------------------------------

def test_knee_segment_is_winters_shank_and_foot_of_a_70_kg_1_75_m_adult(knee):
    leg_m = WINTER_LEG_SHARE * HEIGHT_M
    mass = WINTER_MASS_SHARE * BODY_MASS_KG
    j = knee.joint
    assert j.mass_kg == pytest.approx(mass, abs=0.005)
    assert j.com_distance_m == pytest.approx(WINTER_COM_SHARE * leg_m, abs=0.0005)
    assert j.inertia_kg_m2 == pytest.approx(mass * (WINTER_GYRATION_SHARE * leg_m) ** 2,
                                            abs=0.0005)
    assert j.initial_angle_rad == 0.0 and j.equilibrium_rad == 0.0


def test_knee_passive_joint_is_the_pendulum_test_of_paraplegic_knees(knee):
    assert knee.joint.stiffness_n_m_per_rad == PENDULUM_K
    assert knee.joint.damping_n_m_s_per_rad == PENDULUM_B


def test_knee_quadriceps_is_the_fes_quadriceps_preset_but_for_its_parallel_spring(knee):
    preset, _ = load_muscle_params(FES_QUADRICEPS)
    q = muscle(knee, 'quadriceps')
    assert q.action == 'extensor'
    assert min(PATELLAR_ARMS_M) <= q.moment_arm_m <= max(PATELLAR_ARMS_M)
    assert q.params.replace(k_pe_n_per_m=preset.k_pe_n_per_m) == preset


def test_knee_muscles_are_at_their_optimum_at_60_deg_of_flexion(knee):
    # theta = 0 is 90 deg of flexion.
    optimum = math.radians(90.0 - OPTIMAL_FLEXION_DEG)
    for m in knee.muscles:
        assert m.reference_angle_rad == pytest.approx(optimum, abs=1e-4)
        assert m.params.l_rest_m == m.params.l_opt_m
    # The quadriceps' force-length factor hanging and horizontal (doc/model.md and doc/limb.md).
    q = muscle(knee, 'quadriceps')
    for theta, expected in ((0.0, 0.86), (math.pi / 2, 0.45)):
        x = (q.params.l_rest_m + q.dl_mt(theta)) / q.params.l_opt_m
        assert fl(x) == pytest.approx(expected, abs=0.005)


def test_knee_hamstrings_are_rajagopals_scaled_as_the_quadriceps(knee):
    forces = {k: v[0] for k, v in RAJAGOPAL_HAMSTRINGS.items()}
    total = sum(forces.values())
    weighted = {i: sum(forces[k] * v[i] for k, v in RAJAGOPAL_HAMSTRINGS.items()) / total
                for i in (1, 2)}
    h = muscle(knee, 'hamstrings')
    p = h.params
    assert h.action == 'flexor'
    arm = sum(forces[k] * HAMSTRING_ARMS_M[k] for k in forces) / total
    assert h.moment_arm_m == pytest.approx(arm, abs=0.0005)
    assert p.f_iso_max_n == pytest.approx(
        total * FES_QUADRICEPS_N / sum(RAJAGOPAL_QUADRICEPS_N), abs=0.1)
    assert p.l_opt_m == pytest.approx(weighted[1], abs=0.0001)
    assert p.k_se_n_per_m == pytest.approx(total / (OPENSIM_TENDON_STRAIN * weighted[2]),
                                           rel=1e-3)
    assert p.fv_a_n == pytest.approx(OPENSIM_HILL_A * p.f_iso_max_n, abs=0.1)
    assert p.fv_b_m_per_s == pytest.approx(OPENSIM_HILL_A * OPENSIM_V_MAX * p.l_opt_m,
                                           abs=0.001)
    assert p.fv_a_ecc_n == p.fv_a_n
    assert p.fv_b_ecc_m_per_s == pytest.approx(PAPER_ECC_B_RATIO * p.fv_b_m_per_s,
                                               abs=0.001)


@pytest.mark.parametrize('path', [KNEE, ANKLE], ids=['knee', 'ankle'])
def test_parallel_springs_are_one_percent_of_the_joint_stiffness(path):
    plant, _ = load_plant(path)
    for m in plant.muscles:
        expected = PE_SHARE_OF_K * plant.joint.stiffness_n_m_per_rad / m.moment_arm_m ** 2
        assert m.params.k_pe_n_per_m == pytest.approx(expected, rel=0.005), m.name


@pytest.mark.parametrize('path', [KNEE, ANKLE], ids=['knee', 'ankle'])
def test_every_muscle_has_a_curve_a_delay_activation_and_fatigue(path):
    plant, node = load_plant(path)
    assert node == {'rate_hz': 1000.0}
    for m in plant.muscles:
        p = m.params
        assert p.recruitment_curve == 'exponential'
        assert p.pw_threshold_s < p.pw_max_s
        assert p.emd_s > 0.0 and p.tau_act_s > 0.0 and p.tau_deact_s > 0.0
        assert p.fatigue == 'riener' and p.recruitment_order == 'random'
        assert p.fv_scaling == 'relative'
        assert (p.units, p.length) == ('multi', 'initial')


# -- The ankle: values from their sources --------------------------------------------

def test_ankle_foot_and_tibialis_anterior_are_the_drop_foot_model(ankle):
    j = ankle.joint
    for key, value in FOOT.items():
        assert getattr(j, key) == value, key
    ta = muscle(ankle, 'tibialis_anterior')
    assert ta.action == 'extensor' and ta.moment_arm_m == TA_ARM_M
    assert ta.params.f_iso_max_n == TA_FORCE_N
    assert (ta.params.tau_act_s, ta.params.tau_deact_s) == TA_TAU_S


def test_ankle_spring_is_the_secant_of_riener_and_edrichs_passive_moment(ankle):
    slack_deg = brentq(riener_edrich_ankle_n_m, -40.0, 10.0)
    secant = -riener_edrich_ankle_n_m(0.0) / math.radians(-slack_deg)
    j = ankle.joint
    assert j.stiffness_n_m_per_rad == pytest.approx(secant, abs=0.005)
    assert j.equilibrium_rad == pytest.approx(math.radians(90.0 + slack_deg), abs=1e-4)
    # The linear spring needs the exponential's torque at the neutral ankle.
    assert j.stiffness_n_m_per_rad * (math.pi / 2 - j.equilibrium_rad) == pytest.approx(
        -riener_edrich_ankle_n_m(0.0), rel=1e-3)


def test_ankle_tibialis_anterior_tendon_and_hill_constants_follow_rajagopal_and_opensim(
        ankle):
    f_max, l_opt, l_slack = RAJAGOPAL_TIBIALIS_ANTERIOR
    p = muscle(ankle, 'tibialis_anterior').params
    assert p.l_opt_m == l_opt == p.l_rest_m
    assert p.k_se_n_per_m == pytest.approx(f_max / (OPENSIM_TENDON_STRAIN * l_slack),
                                           rel=1e-3)
    assert p.fv_a_n == OPENSIM_HILL_A * p.f_iso_max_n == p.fv_a_ecc_n
    assert p.fv_b_m_per_s == pytest.approx(OPENSIM_HILL_A * OPENSIM_V_MAX * l_opt, abs=0.001)
    assert p.fv_b_ecc_m_per_s == pytest.approx(PAPER_ECC_B_RATIO * p.fv_b_m_per_s,
                                               abs=0.001)


def test_drop_foot_starts_at_rest_in_20_deg_of_plantarflexion(ankle):
    rest = rest_angle(ankle)
    assert ankle.joint.initial_angle_rad == pytest.approx(rest, abs=1e-4)
    assert math.degrees(rest) - 90.0 == pytest.approx(-20.8, abs=0.05)
    relaxed = simulate_limb(ankle, LimbProtocol.from_mapping({
        'name': 'relaxed', 'duration_s': 2.0,
        'muscles': {'tibialis_anterior': {'recruitment': [[0.0, 0.0]]}}}))
    assert np.ptp(relaxed['theta_rad']) < math.radians(0.01)


# -- Plausibility ----------------------------------------------------------------------

#: [s] the reach protocols: rest, then a constant pulse width to the end.
KNEE_ON_S, KNEE_DURATION_S = 0.2, 3.5
ANKLE_ON_S, ANKLE_DURATION_S = 0.2, 1.5
#: The smallest reaching width lies within this share of the static estimate:
#: the run differs from the static balance by fatigue during the rise (a few %
#: in 1-2 s with 20-60 s time constants), the force-velocity relation while the
#: joint moves and the overshoot of an underdamped joint (both < 5 % here).
STATIC_ESTIMATE_TOLERANCE = 0.10


@pytest.mark.slow
def test_knee_extends_from_hanging_to_horizontal_inside_the_stimulators_range(knee):
    horizontal = math.pi / 2
    pw = smallest_pulse_width_reaching(knee, 'quadriceps', horizontal, KNEE_ON_S,
                                       KNEE_DURATION_S)
    p = muscle(knee, 'quadriceps').params
    assert p.pw_threshold_s < pw < p.pw_max_s
    estimate = static_pulse_width(knee, 'quadriceps', horizontal)
    assert pw == pytest.approx(estimate, rel=STATIC_ESTIMATE_TOLERANCE)
    # The numbers doc/limb.md quotes: 359 us, the static estimate 351 us.
    assert pw == pytest.approx(359e-6, abs=2e-6)
    assert estimate == pytest.approx(351e-6, abs=1e-6)


def test_drop_foot_is_lifted_to_the_neutral_ankle_inside_the_stimulators_range(ankle):
    neutral = math.pi / 2
    pw = smallest_pulse_width_reaching(ankle, 'tibialis_anterior', neutral, ANKLE_ON_S,
                                       ANKLE_DURATION_S)
    p = muscle(ankle, 'tibialis_anterior').params
    assert p.pw_threshold_s < pw < p.pw_max_s
    estimate = static_pulse_width(ankle, 'tibialis_anterior', neutral)
    assert pw == pytest.approx(estimate, rel=STATIC_ESTIMATE_TOLERANCE)
    # The numbers doc/limb.md quotes: 225 us, the static estimate 224 us.
    assert pw == pytest.approx(225e-6, abs=2e-6)
    assert estimate == pytest.approx(224e-6, abs=1e-6)


#: [deg] release angle of the pendulum test.
RELEASE_DEG = 30.0
PENDULUM_DURATION_S = 6.0
#: Each full period lies within 1 % of the small-angle 2 pi sqrt(J / (m g l_c + K)):
#: damping lengthens it by 1 / sqrt(1 - zeta^2) (+0.19 %), the 30 deg amplitude by at
#: most (m g l_c / k) theta_0^2 / 16 (+0.7 %, the first swing; gravity is 42 % of
#: the stiffness), and the quadriceps' parallel spring, stretched over the whole
#: swing, stiffens the joint by k_PE r^2 / k (0.6 %, -0.3 %).
PERIOD_TOLERANCE = 0.01
#: The damping ratio from the peaks' logarithmic decrement lies within 2 % of
#: B / (2 sqrt(J k)): the amplitude and the parallel spring shift k by < 1 %.
DAMPING_TOLERANCE = 0.02


@pytest.fixture(scope='module')
def pendulum(knee):
    released = LimbPlant(dataclasses.replace(
        knee.joint, initial_angle_rad=math.radians(RELEASE_DEG)), knee.muscles)
    protocol = LimbProtocol.from_mapping({
        'name': 'pendulum test', 'duration_s': PENDULUM_DURATION_S,
        'muscles': {'quadriceps': {'recruitment': [[0.0, 0.0]]}}})
    r = simulate_limb(released, protocol)
    return r.t_s, r['theta_rad'] - rest_angle(knee)


def test_relaxed_knee_swings_with_the_pendulum_tests_period(knee, pendulum):
    t, y = pendulum
    k = (knee.joint.mass_kg * knee.joint.gravity_m_per_s2 * knee.joint.com_distance_m
         + knee.joint.stiffness_n_m_per_rad)
    small_angle = 2.0 * math.pi * math.sqrt(knee.joint.inertia_kg_m2 / k)
    down = np.nonzero((y[:-1] > 0.0) & (y[1:] <= 0.0))[0]
    crossings = t[down] + y[down] / (y[down] - y[down + 1]) * (t[down + 1] - t[down])
    periods = np.diff(crossings)
    assert len(periods) >= 6
    np.testing.assert_allclose(periods, small_angle, rtol=PERIOD_TOLERANCE)
    # The number doc/limb.md quotes: 0.80 s.
    assert small_angle == pytest.approx(0.80, abs=0.005)


def test_relaxed_knee_decays_with_the_pendulum_tests_damping(knee, pendulum):
    t, y = pendulum
    j = knee.joint
    k = j.mass_kg * j.gravity_m_per_s2 * j.com_distance_m + j.stiffness_n_m_per_rad
    zeta = j.damping_n_m_s_per_rad / (2.0 * math.sqrt(j.inertia_kg_m2 * k))
    peaks = np.nonzero((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:]) & (y[1:-1] > 0.0))[0] + 1
    decrement = np.log(y[peaks][:-1] / y[peaks][1:])
    measured = decrement / np.sqrt(4.0 * math.pi ** 2 + decrement ** 2)
    assert len(measured) >= 5
    np.testing.assert_allclose(measured, zeta, rtol=DAMPING_TOLERANCE)
    assert zeta == pytest.approx(0.061, abs=0.0005)   # doc/limb.md's number
