"""The limb in the ``hill-muscle`` command: ``simulate --plant``, the limb
figure and ``animate``.

The CSV and the table are compared with the core (``simulate_limb``) run on
the same plant and protocol; the limb figure's claim is checked against static
torque balances written here; the GIF is read back with Pillow.
"""
import math
import os
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.optimize import brentq

from hill_muscle_ros import resources
from hill_muscle_ros.model.limb import LimbProtocol, simulate_limb
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.tools import cli

HILL_MUSCLE = Path(sys.executable).with_name('hill-muscle')
#: [s] generous: the machine is shared with other test runs.
SUBPROCESS_TIMEOUT_S = 120
KNEE = resources.config_dir() / 'knee.yaml'
ANKLE = resources.config_dir() / 'ankle.yaml'
KNEE_EXTENSION = resources.config_dir() / 'protocols' / 'knee_extension.yaml'
#: The CSV header of the knee plant, written out.
KNEE_CSV_HEADER = (
    't_s,theta_rad,omega_rad_per_s,'
    'quadriceps_command,quadriceps_recruitment,quadriceps_dl_mt_m,quadriceps_l_ce_m,'
    'quadriceps_force_n,'
    'hamstrings_command,hamstrings_recruitment,hamstrings_dl_mt_m,hamstrings_l_ce_m,'
    'hamstrings_force_n')
#: A short knee protocol (2.5 s) with both muscles and an external push.
SHORT_PROTOCOL = """\
name: short knee run
duration_s: 2.5
muscles:
  quadriceps:
    pulse_width_s: [[0.2, 0.0], [0.2, 0.0003], [1.5, 0.0003], [1.5, 0.0]]
  hamstrings:
    recruitment: [[0.0, 0.0], [1.8, 0.0], [1.8, 0.2]]
external_torque_n_m: [[0.0, 0.0], [1.0, 0.0], [1.0, 2.0], [1.2, 2.0], [1.2, 0.0]]
"""


def run_cli(*args):
    """Run the installed console script; return the completed process."""
    return subprocess.run([str(HILL_MUSCLE), *map(str, args)], capture_output=True,
                          text=True, env=os.environ.copy(), timeout=SUBPROCESS_TIMEOUT_S)


def run_main(capsys, *args):
    """Run the command's entry function ``cli.main`` in this process; return
    what a subprocess would: exit status and the text written to each stream."""
    capsys.readouterr()
    status = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return types.SimpleNamespace(returncode=status, stdout=out, stderr=err)


def read_csv(path):
    """Header line and the data as a 2-D array."""
    with open(path, encoding='utf-8') as f:
        header = f.readline().rstrip('\n')
    return header, np.loadtxt(path, delimiter=',', skiprows=1, ndmin=2)


@pytest.fixture(scope='module')
def short_protocol(tmp_path_factory):
    """The short protocol's file, written once: every test only reads it."""
    path = tmp_path_factory.mktemp('protocol') / 'short.yaml'
    path.write_text(SHORT_PROTOCOL)
    return path


def core(plant_path, protocol_path, rate_hz=1000.0):
    plant, _ = load_plant(plant_path)
    return simulate_limb(plant, LimbProtocol.from_yaml(protocol_path), rate_hz)


@pytest.fixture(scope='module')
def knee_core(short_protocol):
    """The core's knee run on the short protocol at 1 kHz (1-2 s), computed once
    for the tests that compare the command's output with it."""
    return core(KNEE, short_protocol)


@pytest.fixture(scope='module')
def knee_csv(tmp_path_factory, short_protocol):
    """``simulate --plant knee.yaml --csv`` on the short protocol at the default
    rate, run once: header and data."""
    out = tmp_path_factory.mktemp('knee_csv') / 'knee.csv'
    assert cli.main(['simulate', '--plant', str(KNEE), '--protocol', str(short_protocol),
                     '--csv', str(out)]) == 0
    return read_csv(out)


# --------------------------------------------------------------------------- CSV

def test_limb_csv_header_is_exact(knee_csv):
    assert knee_csv[0] == KNEE_CSV_HEADER


def test_limb_csv_has_one_row_per_step_from_zero_to_the_end(knee_csv):
    _, data = knee_csv
    assert data.shape == (2501, len(KNEE_CSV_HEADER.split(',')))
    assert data[0, 0] == 0.0 and data[-1, 0] == 2.5


def test_limb_rate_option_sets_the_step(tmp_path, short_protocol):
    out = tmp_path / 'knee.csv'
    assert cli.main(['simulate', '--plant', str(KNEE), '--protocol', str(short_protocol),
                     '--rate', '400', '--csv', str(out)]) == 0
    _, data = read_csv(out)
    assert len(data) == 1001
    np.testing.assert_allclose(np.diff(data[:, 0]), 0.0025, rtol=1e-9)


def test_limb_csv_values_equal_simulate_limb_exactly(knee_csv, knee_core):
    header, data = knee_csv
    expected = knee_core
    for i, column in enumerate(header.split(',')):
        np.testing.assert_array_equal(data[:, i], expected[column], err_msg=column)


def test_limb_simulate_from_the_console_script_writes_the_ankle(tmp_path):
    protocol = tmp_path / 'lift.yaml'
    protocol.write_text('name: lift\nduration_s: 1.0\nmuscles:\n  tibialis_anterior:\n'
                        '    pulse_width_s: [[0.1, 0.0], [0.1, 0.0003]]\n')
    out = tmp_path / 'ankle.csv'
    proc = run_cli('simulate', '--plant', ANKLE, '--protocol', protocol, '--csv', out)
    assert proc.returncode == 0, proc.stderr
    header, data = read_csv(out)
    assert header.split(',')[3:] == [f'tibialis_anterior_{c}' for c in
                                     ('command', 'recruitment', 'dl_mt_m', 'l_ce_m', 'force_n')]
    np.testing.assert_array_equal(data[:, 1], core(ANKLE, protocol)['theta_rad'])


# --------------------------------------------------------------------------- table

def test_limb_table_prints_the_angle_in_degrees_and_each_force_each_second(
        capsys, short_protocol, knee_core):
    assert cli.main(['simulate', '--plant', str(KNEE), '--protocol',
                     str(short_protocol)]) == 0
    lines = capsys.readouterr().out.splitlines()
    header = lines[1].split()
    assert header == ['t_s', 'theta_deg', 'quadriceps_force_n', 'hamstrings_force_n']
    rows = [dict(zip(header, map(float, line.split()))) for line in lines[2:]]
    expected = knee_core
    assert [r['t_s'] for r in rows] == [1.0, 2.0, 2.5]
    for row in rows:
        k = int(round(row['t_s'] * 1000.0))
        # The table prints degrees to 2 decimals and forces to 1.
        assert row['theta_deg'] == pytest.approx(math.degrees(expected['theta_rad'][k]),
                                                 abs=0.005)
        for name in ('quadriceps', 'hamstrings'):
            assert row[f'{name}_force_n'] == pytest.approx(expected[f'{name}_force_n'][k],
                                                           abs=0.05)


# --------------------------------------------------------------------------- errors

def assert_user_error(proc, *fragments):
    assert proc.returncode == 2
    assert 'Traceback' not in proc.stderr
    assert proc.stderr.strip().count('\n') == 0, proc.stderr  # one line
    for fragment in fragments:
        assert fragment in proc.stderr, proc.stderr


def write_plant(tmp_path, body):
    path = tmp_path / 'plant.yaml'
    path.write_text('/**:\n  ros__parameters:\n' + textwrap.indent(textwrap.dedent(body), '    '))
    return path


PLANT_BODY = """\
joint:
  inertia_kg_m2: {inertia}
muscles: [quadriceps]
quadriceps:
  action: extensor
{arm}  f_iso_max_n: 1500.0
"""


def test_protocol_naming_an_unknown_muscle_exits_2_naming_it(tmp_path):
    plant = write_plant(tmp_path, PLANT_BODY.format(inertia=0.428,
                                                    arm='  moment_arm_m: 0.04\n'))
    protocol = tmp_path / 'p.yaml'
    protocol.write_text('name: p\nduration_s: 1.0\nmuscles:\n  vastus:\n'
                        '    recruitment: [[0.0, 0.5]]\n')
    assert_user_error(run_cli('simulate', '--plant', plant, '--protocol', protocol),
                      str(protocol), '`vastus`')


# The console script itself exits 2 in the test above; the other plant errors go through its entry function in this process
# (a subprocess each re-imported numpy and the package, 0.2-0.4 s apiece).

def test_plant_without_a_moment_arm_exits_2_naming_the_key(tmp_path, short_protocol, capsys):
    plant = write_plant(tmp_path, PLANT_BODY.format(inertia=0.428, arm=''))
    assert_user_error(run_main(capsys, 'simulate', '--plant', plant, '--protocol', short_protocol),
                      str(plant), 'quadriceps.moment_arm_m')


def test_plant_with_a_negative_inertia_exits_2_naming_the_key(tmp_path, short_protocol,
                                                          capsys):
    plant = write_plant(tmp_path, PLANT_BODY.format(inertia=-0.428,
                                                    arm='  moment_arm_m: 0.04\n'))
    assert_user_error(run_main(capsys, 'simulate', '--plant', plant, '--protocol', short_protocol),
                      str(plant), 'joint.inertia_kg_m2', '-0.428')


@pytest.mark.parametrize('option', [['--units', 'single'], ['--length', 'instantaneous'],
                                    ['--params', str(KNEE)]])
def test_single_muscle_options_with_a_plant_exit_2_naming_the_option(
        capsys, short_protocol, option):
    assert cli.main(['simulate', '--plant', str(KNEE), '--protocol', str(short_protocol),
                     *option]) == 2
    assert option[0] in capsys.readouterr().err


# --------------------------------------------------------------------------- animate

#: [Hz] step rate of the GIFs written here (a fifth of the knee's 1 kHz).
ANIMATE_TEST_RATE_HZ = 200

def test_animate_help_exits_zero():
    proc = run_cli('animate', '--help')
    assert proc.returncode == 0, proc.stderr
    assert 'usage: hill-muscle animate' in proc.stdout


@pytest.mark.parametrize('fps,frames', [(10.0, 26), (4.0, 11)])
def test_animate_writes_a_gif_with_one_frame_per_1_over_fps(tmp_path, short_protocol, fps,
                                                            frames):
    out = tmp_path / 'sub' / 'leg.gif'
    # At 200 Hz: the frames sample simulated time at 1 / fps whatever the step;
    # the plant file's own rate (1 kHz) is the path the CSV tests above take.
    assert cli.main(['animate', '--plant', str(KNEE), '--protocol', str(short_protocol),
                     '--out', str(out), '--fps', str(fps),
                     '--rate', str(ANIMATE_TEST_RATE_HZ)]) == 0
    with Image.open(out) as gif:
        assert gif.format == 'GIF'
        # 2.5 s: frames at 0, 1 / fps, ..., 2.5 s.
        assert gif.n_frames == frames == math.floor(2.5 * fps) + 1
        assert gif.info['duration'] == int(1000 / fps)


@pytest.mark.parametrize('fps', ['0', '-5', 'fast', '500'])
def test_animate_bad_fps_exits_2(tmp_path, short_protocol, capsys, fps):
    assert cli.main(['animate', '--plant', str(KNEE), '--protocol', str(short_protocol),
                     '--out', str(tmp_path / 'x.gif'), '--fps', fps]) == 2
    assert '--fps' in capsys.readouterr().err


def test_animate_with_a_bad_plant_exits_2_naming_the_key(tmp_path, short_protocol, capsys):
    # The entry function in this process: `animate`'s console script runs in
    # test_animate_help_exits_zero (a second one here cost 0.8 CPU-s).
    plant = write_plant(tmp_path, PLANT_BODY.format(inertia=-1.0,
                                                    arm='  moment_arm_m: 0.04\n'))
    assert_user_error(run_main(capsys, 'animate', '--plant', plant, '--protocol', short_protocol,
                               '--out', tmp_path / 'x.gif'), 'joint.inertia_kg_m2')


# --------------------------------------------------------------------------- figure

def fl(x):
    """The paper's force-length relation (Eq. 1), written here."""
    return max(0.0, -2.777 * x * x + 5.554 * x - 1.777)


def riener_whole_muscle_fitness(t_s, activation, p):
    """[-] Riener's whole-muscle fitness under activation a(t), by explicit Euler
    on the recorded samples (time constants >= 30 s against a 1 ms step)."""
    mu = np.ones_like(t_s)
    dt = np.diff(t_s)
    mu_min, t_fat, t_rec = p.fatigue_min[0], p.tau_fatigue_s[0], p.tau_recovery_s[0]
    for k in range(len(dt)):
        a = activation[k]
        mu[k + 1] = mu[k] + dt[k] * ((mu_min - mu[k]) * a / t_fat
                                     + (1.0 - mu[k]) * (1.0 - a) / t_rec)
    return mu


def static_angle(plant, f0_of_x, x_of_theta):
    """[rad] the angle where the quadriceps' isometric force F0 (from FL at
    ``x_of_theta``) balances gravity, the joint spring and the parallel springs."""
    j = plant.joint

    def torque(theta):
        tau = (-j.mass_kg * j.gravity_m_per_s2 * j.com_distance_m * math.sin(theta)
               - j.stiffness_n_m_per_rad * (theta - j.equilibrium_rad))
        for m in plant.muscles:
            sign = 1.0 if m.action == 'extensor' else -1.0
            dl = -sign * m.moment_arm_m * (theta - m.reference_angle_rad)
            tau += sign * m.moment_arm_m * m.params.k_pe_n_per_m * max(dl, 0.0)
        q = plant.muscles[0]
        return tau + q.moment_arm_m * f0_of_x(x_of_theta(theta))

    return brentq(torque, 0.0, math.pi / 2 + 0.5)


#: Passes of the CE-length fixed point in the static balance.
FIXED_POINT_PASSES = 5
#: [deg] The simulated end angle lies this close to the static balance: 1.5 s
#: after the last step the joint has settled (activation 25 ms, the muscle's
#: force-velocity damping) and fatigue moves it by < 0.1 deg/s.
STATIC_TOLERANCE_DEG = 0.5


@pytest.fixture(scope='module')
def limb_figure():
    from hill_muscle_ros.tools.figures import limb
    return limb, limb.limb_data()


@pytest.mark.slow
def test_limb_figure_single_unit_end_angles_are_the_static_balances(limb_figure):
    """At the end of the last hold the knee is static: with a single unit the
    angle is where R mu f_iso_max FL balances the passive torque, with FL at the
    length stored when R rose from 0 (initial) or at the current CE length
    (instantaneous, the tendon's stretch F / k_SE included)."""
    limb, data = limb_figure
    plant, _ = load_plant(KNEE)
    q = plant.muscles[0]
    p = q.params
    for variant in limb.VARIANTS:
        if variant.units != 'single':
            continue
        r = data.results[variant]
        k = int(np.argmin(np.abs(r.t_s - data.compare_s)))
        rec = r['quadriceps_recruitment']
        mu = riener_whole_muscle_fitness(r.t_s, rec, limb.limb_variant_plant(
            plant, 'single', variant.length).muscles[0].params)
        scale = rec[k] * mu[k] * p.f_iso_max_n
        if variant.length == 'initial':
            rise = int(np.nonzero(rec > 0.0)[0][0])
            x_stored = r['quadriceps_l_ce_m'][rise] / p.l_opt_m
            theta = static_angle(plant, lambda x: scale * fl(x), lambda th: x_stored)
        else:
            def x_now(th):
                # Fixed point: the tendon's stretch F / k_SE shortens the CE (by
                # about 1 mm: each pass shrinks the error a hundredfold).
                dl = -q.moment_arm_m * (th - q.reference_angle_rad)
                force = 0.0
                for _ in range(FIXED_POINT_PASSES):
                    x = (p.l_rest_m + dl - force / p.k_se_n_per_m) / p.l_opt_m
                    force = scale * fl(x)
                return x
            theta = static_angle(plant, lambda x: scale * fl(x), x_now)
        assert data.angle_deg(variant) == pytest.approx(math.degrees(theta),
                                                        abs=STATIC_TOLERANCE_DEG), variant


@pytest.mark.slow
def test_limb_figure_initial_length_ends_far_above_instantaneous(limb_figure):
    limb, data = limb_figure
    single_initial, multi_initial, single_inst, multi_inst = limb.VARIANTS
    # The paper's point in motion: units recruited on the long, hanging CE keep
    # FL of that length (0.86) with initial memory; with the instantaneous length
    # FL falls to 0.45 as the knee extends.
    assert data.spread_deg(multi_initial, multi_inst) > 15.0
    assert data.spread_deg(single_initial, single_inst) > 15.0
    # With instantaneous length single and multiple units coincide (M / N = R up
    # to the rounding of M).
    assert abs(data.spread_deg(single_inst, multi_inst)) < 1.5
    # The numbers doc/limb.md quotes (22.6 and 16.9 deg, single 4.6 deg below multi).
    assert data.spread_deg(multi_initial, multi_inst) == pytest.approx(22.6, abs=0.05)
    assert data.spread_deg(single_initial, single_inst) == pytest.approx(16.9, abs=0.05)
    assert data.spread_deg(single_initial, multi_initial) == pytest.approx(-4.6, abs=0.05)


@pytest.mark.slow
def test_limb_figure_is_written_by_the_figures_command(tmp_path, limb_figure):
    limb, data = limb_figure
    path = limb.write_limb_figure(tmp_path, data=data)
    assert path == tmp_path / 'limb_knee.png'
    with Image.open(path) as png:
        assert png.format == 'PNG' and png.size == (800, 800)
