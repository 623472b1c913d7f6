"""Benchmark: faster than real time over ROS 2, on sim time.

For each real-time factor, the demo's live run (:mod:`hill_muscle_ros.demo`):
the simulator with ``publish_clock`` and ``real_time_factor``, the recorder
and the protocol player on ``use_sim_time``, three processes, Protocol II.
The length goes ahead as ``length_command_stamped`` knots, ``lookahead``
simulated seconds ahead (the demo's default, :func:`default_lookahead_s`,
or ``--lookahead``; 0 is the plain ``length_command``).
Per run: the largest |recorded force - offline force| at the end of each
second (split into held-length and mid-ramp seconds; the recorded sample is
the last wrench at or before the time, compared with the offline force at
that sample's own time), the achieved real-time factor (the simulator's
simulated seconds / steady seconds, from its exit statistics), the
simulator's catch-up warnings, steps behind at exit and late length knots.
The 0.5 N criterion holds at a factor if it holds in every run at it. The
sweep stops after two factors in a row at which no run holds it.

Usage (also called by run_all.py)::

    .venv/bin/python benchmarks/bench_rtf.py [--runs 3] [--rtf 1 2 5 10 20 50 100]
        [--lookahead S]
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from hill_muscle_ros.demo import (DemoConfig, DemoError, record_live_run,  # noqa: E402
                                  simulator_stats)
from hill_muscle_ros.model import Muscle, Protocol, simulate  # noqa: E402
from hill_muscle_ros.params_file import load_muscle_params  # noqa: E402
from hill_muscle_ros.recording.analysis import (BagContentError, live_samples_at,  # noqa: E402
                                                summary_times)
from hill_muscle_ros.recording.reader import read_bag  # noqa: E402
from hill_muscle_ros.resources import default_params_file, protocol_path  # noqa: E402

DEFAULT_RTFS = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
DEFAULT_RUNS = 3
#: [N] the pass criterion: every end-of-second reading within this of offline.
FORCE_TOLERANCE_N = 0.5
OUT_DIR = REPO / 'runs' / 'bench_rtf'
#: The sweep stops after this many factors in a row at which no run held.
STOP_AFTER_FAILING = 2


@dataclass
class RtfResult:
    rtf: float
    max_err_held_n: list[float] = field(default_factory=list)
    max_err_ramp_n: list[float] = field(default_factory=list)
    achieved_rtf: list[float] = field(default_factory=list)
    catch_up_warnings: list[int] = field(default_factory=list)
    steps_behind: list[int] = field(default_factory=list)
    late_knots: list[int] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    #: [s] of simulated time the length was sent ahead (0: plain length_command)
    lookahead_s: float = 0.0
    #: [N] mid-ramp error of the offline core with inputs held for rtf steps
    zoh_err_ramp_n: float = float('nan')

    @property
    def max_err_n(self) -> list[float]:
        return [max(h, r) for h, r in zip(self.max_err_held_n, self.max_err_ramp_n)]

    @property
    def holds(self) -> bool:
        return (not self.failures and bool(self.max_err_n)
                and all(e <= FORCE_TOLERANCE_N for e in self.max_err_n))

    @property
    def never_holds(self) -> bool:
        """No run held the criterion (runs that failed to record count as not holding)."""
        return all(e > FORCE_TOLERANCE_N for e in self.max_err_n)


def _ramping(protocol: Protocol, t_s: float) -> bool:
    h = 1e-3
    return float(protocol.dl_mt(t_s + h)) != float(protocol.dl_mt(t_s - h))


def held_input_error_n(protocol: Protocol, params, offline, rate_hz: float,
                       hold_steps: int) -> float:
    """[N] the floor from input sampling alone, no DDS: the largest mid-ramp error
    at the end-of-second readings of the core fed the protocol through a
    zero-order hold of ``hold_steps`` steps (what a simulator tick of that many
    steps sees at best), against the offline run."""
    muscle, dt_s = Muscle(params), 1.0 / rate_hz
    n = round(protocol.duration_s * rate_hz)
    force = [0.0]
    for k in range(n):
        t_held = (k // hold_steps) * hold_steps * dt_s
        force.append(muscle.step(protocol.recruitment(t_held, params.pw_max_s),
                                 float(protocol.dl_mt(t_held)), dt_s).force_n)
    return max(abs(force[round(t * rate_hz)] - float(offline.force_n[offline.at(t)]))
               for t in summary_times(protocol.duration_s) if _ramping(protocol, t))


#: [s] stimulation delays whose effect on the readings is computed offline
LATE_STIMULATION_S = (0.01, 0.05, 0.1)


def late_stimulation_error_n(protocol: Protocol, params, offline, rate_hz: float,
                             delay_s: float) -> float:
    """[N] the largest change of the end-of-second readings when every
    stimulation change acts ``delay_s`` late and the length is on time, as
    with the length sent ahead and the stimulation on its plain topic (the
    offline core, no DDS)."""
    muscle, dt_s = Muscle(params), 1.0 / rate_hz
    delay = round(delay_s * rate_hz)
    force = [0.0]
    for k in range(round(protocol.duration_s * rate_hz)):
        r = protocol.recruitment((k - delay) * dt_s, params.pw_max_s) if k >= delay else 0.0
        force.append(muscle.step(float(r), float(protocol.dl_mt((k + 1) * dt_s)), dt_s).force_n)
    return max(abs(force[round(t * rate_hz)] - float(offline.force_n[offline.at(t)]))
               for t in summary_times(protocol.duration_s))


def one_run(rtf: float, index: int, protocol: Protocol, offline, rate_hz: float,
            result: RtfResult, lookahead_s: float | None = None) -> None:
    """One live run at ``rtf``; appends its numbers (or its failure) to ``result``."""
    name = f'rtf_{rtf:g}_{index}_{time.strftime("%H%M%S")}'
    bag_dir, log_dir = OUT_DIR / name, OUT_DIR / 'logs' / name
    log_dir.mkdir(parents=True, exist_ok=True)
    times = summary_times(protocol.duration_s)
    config = DemoConfig(protocol='II', real_time_factor=rtf, lookahead_s=lookahead_s)
    result.lookahead_s = config.lookahead()
    try:
        record_live_run(config, bag_dir, protocol, log_dir)
        bag = read_bag(bag_dir)
        samples = live_samples_at(bag, times, sim_time=True)
    except (DemoError, BagContentError) as err:   # e.g. the recorder matched the player late
        result.failures.append(str(err).splitlines()[0].replace(str(REPO) + '/', ''))
        return
    err = {t: abs(f - float(offline.force_n[offline.at(t_f)]))
           for t, (t_f, f) in zip(times, samples)}
    result.max_err_held_n.append(max(e for t, e in err.items() if not _ramping(protocol, t)))
    result.max_err_ramp_n.append(max(e for t, e in err.items() if _ramping(protocol, t)))
    stats = simulator_stats((log_dir / 'simulator.log').read_text(errors='replace'))
    if stats is not None:
        result.achieved_rtf.append(stats.achieved_rtf(rate_hz))
        result.catch_up_warnings.append(stats.catch_up_warnings)
        result.steps_behind.append(stats.steps_behind)
        result.late_knots.append(stats.late_knots)


def run(rtfs=DEFAULT_RTFS, runs: int = DEFAULT_RUNS, verbose: bool = True,
        lookahead_s: float | None = None) -> list[RtfResult]:
    """Sweep the factors; ``lookahead_s`` None is the demo's default per factor."""
    protocol = Protocol.from_yaml(protocol_path('II'))
    params, settings = load_muscle_params(default_params_file())
    rate_hz = float(settings.get('rate_hz', 1000.0))
    offline = simulate(protocol, params, rate_hz)
    results, failing = [], 0
    for rtf in rtfs:
        result = RtfResult(rtf)
        result.zoh_err_ramp_n = held_input_error_n(protocol, params, offline, rate_hz,
                                                   max(1, round(rtf)))
        for i in range(runs):
            one_run(rtf, i, protocol, offline, rate_hz, result, lookahead_s)
        results.append(result)
        if verbose:
            print(format_row(result), flush=True)
        # A run the recorder missed (slow discovery) says nothing about the factor.
        failing = failing + 1 if result.never_holds else 0
        if failing >= STOP_AFTER_FAILING:
            break   # clearly fails: higher factors only fail harder
    return results


def _range(values, fmt: str) -> str:
    if not values:
        return '-'
    lo, hi = min(values), max(values)
    return f'{lo:{fmt}}' if lo == hi else f'{lo:{fmt}} - {hi:{fmt}}'


TABLE_HEADER = ('| real_time_factor | look-ahead [s] | runs | max error, held length [N] '
                '| max error, mid-ramp [N] | offline, inputs held RTF steps, mid-ramp [N] '
                '| achieved RTF | catch-up warnings | steps behind at exit | late length knots '
                '| within 0.5 N |\n'
                '| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |')


def format_row(r: RtfResult) -> str:
    n = len(r.max_err_n)
    holds = sum(e <= FORCE_TOLERANCE_N for e in r.max_err_n)
    verdict = f'{"**yes**" if r.holds else "no"} ({holds}/{n + len(r.failures)})'
    if r.failures:
        verdict += f'; failed: {r.failures[0]}'
    return (f'| {r.rtf:g} | {r.lookahead_s:g} | {n + len(r.failures)} | '
            f'{_range(r.max_err_held_n, ".3f")} | '
            f'{_range(r.max_err_ramp_n, ".3f")} | {r.zoh_err_ramp_n:.3f} | '
            f'{_range(r.achieved_rtf, ".2f")} | '
            f'{_range(r.catch_up_warnings, "d")} | {_range(r.steps_behind, "d")} | '
            f'{_range(r.late_knots, "d")} | {verdict} |')


def highest_holding(results: list[RtfResult]) -> float | None:
    ok = [r.rtf for r in results if r.holds]
    return max(ok) if ok else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=DEFAULT_RUNS, help='runs per factor')
    parser.add_argument('--rtf', type=float, nargs='+', default=list(DEFAULT_RTFS),
                        help='real-time factors to try, in increasing order')
    parser.add_argument('--lookahead', type=float, metavar='S',
                        help='simulated seconds the length is sent ahead (0: the plain '
                             'length_command); default: the demo\'s, growing with the factor')
    args = parser.parse_args(argv)
    protocol = Protocol.from_yaml(protocol_path('II'))
    params, settings = load_muscle_params(default_params_file())
    rate_hz = float(settings.get('rate_hz', 1000.0))
    offline = simulate(protocol, params, rate_hz)
    late = ', '.join(f'{d * 1e3:g} ms: {late_stimulation_error_n(protocol, params, offline, rate_hz, d):.4f} N'
                     for d in LATE_STIMULATION_S)
    print(f'offline, stimulation late and length on time, largest change of a reading: {late}')
    print(TABLE_HEADER, flush=True)
    results = run(args.rtf, args.runs, lookahead_s=args.lookahead)
    best = highest_holding(results)
    print(f'highest real-time factor within {FORCE_TOLERANCE_N} N in every run: '
          f'{best:g}' if best is not None else 'within 0.5 N at no factor tried')
    return 0


if __name__ == '__main__':
    sys.exit(main())
