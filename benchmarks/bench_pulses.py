"""The pulse model's cost: section "Pulses and channels" of BENCHMARKS.md (``make bench``).

What it measures, all in this process, on the build ``Muscle`` takes by
default (compiled where numba imports): a ``ding2003`` muscle run by
``Muscle.run_pulses`` (``simulate()``'s one call of the kernels for the
whole protocol; the muscle built and reset outside the timing, as bench_fes
does, since building and resetting N units is O(N) by nature) on a 10 s
isometric-then-stretched protocol of pulse trains whose pulse width alternates
every second (so every channel's recruited set changes every second), with
fatigue, two fibre types in random order and a length spread, at N = 1e3 and
N = 1e6, with one and with four channels. The target: N = 1e6 costs at most
2x N = 1e3 (O(1) in N, as for fatigue).

Run this section alone while developing::

    .venv/bin/python benchmarks/run_all.py --only pulses --runs 5
"""
from __future__ import annotations

import gc

from timing import Stats, repeat

import numpy as np

from hill_muscle_ros.model import Muscle, MuscleParams
from hill_muscle_ros.model.protocol import PulseProtocol
from hill_muscle_ros.model.simulate import protocol_pulses, sample_times

RATE_HZ = 1000.0
UNIT_COUNTS = (1_000, 1_000_000)
CHANNEL_COUNTS = (1, 4)
PROTOCOL_S = 10.0
#: [s] Pulse widths alternated every second: u = 0.4 and 0.8 on the linear curve.
PW_LOW_S, PW_HIGH_S = 200e-6, 400e-6
#: [Hz] Each channel's frequency: 30 Hz, the default of the plain pulse_width input.
FREQUENCY_HZ = 30.0
#: [m] The slow stretch of bench_fes (0.5 mm/s), keeping every unit in FL's support.
STRETCH_M = 0.005
#: The features of the FES N-scaling target, and the pulse model.
FEATURES = {'activation_model': 'ding2003', 'fatigue': 'riener',
            'fibre_fractions': (0.5, 0.5), 'fibre_force_weights': (1.0, 2.0),
            'recruitment_order': 'random', 'unit_length_spread': 0.2}
#: N = 1e6 at most this many times N = 1e3.
TARGET_N_RATIO = 2.0


def protocol(channels: int) -> PulseProtocol:
    """The alternating protocol, the channels' trains offset by 1 / (f C) (fired in turn)."""
    knots = []
    for k in range(round(PROTOCOL_S)):
        pw = PW_HIGH_S if k % 2 else PW_LOW_S
        knots += [[float(k), pw], [k + 1.0, pw]]
    entries = []
    for c in range(channels):
        start = c / (FREQUENCY_HZ * channels)
        entries.append({'frequency_hz': [[0.0, FREQUENCY_HZ]], 'mode': 'single',
                        'pulse_width_s': ([[0.0, 0.0], [start, 0.0]] if start > 0.0 else [])
                        + [[max(t, start), v] for t, v in knots]})
    return PulseProtocol.from_mapping({
        'name': f'bench {channels} channels', 'duration_s': PROTOCOL_S, 'channels': entries,
        'dl_mt_m': [[0.0, 0.0], [PROTOCOL_S, STRETCH_M]]})


def run(runs: int) -> dict:
    """Every measurement of the section: [us/step] per (channels, N)."""
    n_steps = round(PROTOCOL_S * RATE_HZ)
    rows = {}
    print('pulses: simulate() per channel count and N', flush=True)
    for channels in CHANNEL_COUNTS:
        prot = protocol(channels)
        dl_end = np.asarray(prot.dl_mt(sample_times(PROTOCOL_S, RATE_HZ)))[1:]
        for n in UNIT_COUNTS:
            params = MuscleParams(n_units=n, channel_fractions=(1.0,) * channels, **FEATURES)
            times, chans, commands = protocol_pulses(prot, params)
            muscle = Muscle(params)

            def one_run():
                muscle.run_pulses(times, chans, commands, dl_end, 1.0 / RATE_HZ)
            s = repeat(one_run, runs, setup=muscle.reset).scaled(1e6 / n_steps)
            del muscle
            rows[(channels, n)] = s
            print(f'  C={channels} N={n}: {s.fmt()} us/step', flush=True)
            gc.collect()
    return {'runs': runs, 'rows': rows}


def write_section(add, results: dict) -> None:
    """The section of BENCHMARKS.md from :func:`run`'s results."""
    rows = results['rows']
    n_lo, n_hi = UNIT_COUNTS
    add('## Pulses and channels (`activation_model: ding2003`)')
    add('')
    add('`benchmarks/bench_pulses.py`. `Muscle.run_pulses` of a ding2003 muscle (`simulate()`\'s '
        'whole run in one call of the kernels; built and reset outside the timing), '
        f'{PROTOCOL_S:g} s at {RATE_HZ:g} Hz: each channel sends '
        f'{FREQUENCY_HZ:g} Hz single pulses, the channels in turn (offset 1 / (f C)), the '
        f'pulse width alternating every second between {PW_LOW_S * 1e6:g} and '
        f'{PW_HIGH_S * 1e6:g} us (each pulse of a changed width moves the channel\'s '
        'recruited set), the MTU stretched slowly; fatigue (Riener at a_c), two fibre types '
        'in random order, length spread 0.2. Cost per step = the run / '
        f'{round(PROTOCOL_S * RATE_HZ)} steps, median of {results["runs"]} runs.')
    add('')
    add(f'| channels | N = {n_lo:,} [us/step] | N = {n_hi:,} [us/step] | ratio | '
        f'target <= {TARGET_N_RATIO:g}x |')
    add('| ---: | ---: | ---: | ---: | --- |')
    for channels in CHANNEL_COUNTS:
        a, b = rows[(channels, n_lo)], rows[(channels, n_hi)]
        ratio = b.median / a.median
        add(f'| {channels} | {a.fmt()} | {b.fmt()} | {ratio:.2f} | '
            f'{"**met**" if ratio <= TARGET_N_RATIO else "**not met**"} |')
    add('')


__all__ = ['run', 'write_section', 'Stats']
