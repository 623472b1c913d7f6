"""Muscle parameters: one frozen dataclass in SI units with the paper's defaults.

The field names are also the YAML keys of ``config/muscle.yaml`` and the ROS
parameter names of the simulator node. Each field carries its unit, a
description and its valid range in ``dataclasses.field(metadata=...)`` so the
node can build its ``ParameterDescriptor`` from the same source.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

from .equations import DEFAULT_CHRONAXIE_S, DEFAULT_CURRENT_REF_A, FL_A, FL_B, FL_C

UNITS_CHOICES = ('multi', 'single')
LENGTH_CHOICES = ('initial', 'instantaneous')
RECRUITMENT_CURVE_CHOICES = ('linear', 'threshold_linear', 'exponential')
FV_SCALING_CHOICES = ('absolute', 'relative')
FATIGUE_CHOICES = ('none', 'riener')
RECRUITMENT_ORDER_CHOICES = ('size', 'reverse', 'random')
#: The activation model whose muscle is driven by pulse trains per channel
#: (Ding et al. 2003); the other, ``first_order``, by a level.
PULSED_MODEL = 'ding2003'
ACTIVATION_MODEL_CHOICES = ('first_order', PULSED_MODEL)
#: Stimulator profiles (model/stimulator.py, from pyScienceMode 1.1.5's devices).
STIMULATOR_CHOICES = ('generic', 'rehastim2', 'p24')


def type_block_ends(n_units: int, fractions: tuple[float, ...]) -> list[int]:
    """Last unit number of each block (fibre type, or channel territory):
    floor(N cumsum / sum + 0.5).

    :param n_units: N, the muscle's units
    :param fractions: [-] each block's share (any positive scale)
    :return: K block ends; block k owns units ends[k-1] + 1 .. ends[k] (1-based)
    """
    total = sum(fractions)
    ends, acc = [], 0.0
    for f in fractions:
        acc += f
        ends.append(int(math.floor(n_units * acc / total + 0.5)))
    return ends


#: Upper bound of every float parameter: far beyond any muscle, it only turns a
#: typo or an overflow-prone value (1e300 N/m) into an error. The model and
#: the ROS parameter descriptors use the same bound.
_FLOAT_MAX = 1.0e12
#: [-] Smallest normalised force FL(l_rest / l_opt) accepted at rest length.
#: FL (equations.py, Eq. 1) is 1 - 2.777 (x - 1)^2: zero for |x - 1| >= 0.6. A
#: run starts at rest length, and with ``length: initial`` every unit
#: recruited there keeps FL(l_rest / l_opt) for good, so a muscle whose rest
#: length is outside that range makes no active force at all: l_opt_m 0.001
#: for l_rest_m 0.125 (x = 125) is a typo, not a muscle. The bound is 1 % of
#: f_iso_max rather than 0 because the coefficients are given to 3 decimals:
#: near the roots their rounding (up to 0.0005 (x^2 + x + 1), about 0.003 at
#: x = 1.6) is as large as FL itself, so a smaller FL is zero within the
#: model's own precision. Accepted: 0.4029 < l_rest / l_opt < 1.5971 (the
#: paper's muscle: 1.25, FL = 0.83).
MIN_FL_AT_REST = 0.01
#: Most virtual units the memory accepts; far beyond any real motor pool, it
#: only guards against a typo allocating absurd memory in the naive reference.
N_UNITS_MAX = 1_000_000_000
#: Most fibre types: far more than physiology distinguishes (I, IIa, IIx),
#: it only bounds the per-type bookkeeping of the memory.
N_FIBRE_TYPES_MAX = 16
#: Largest ``unit_length_spread`` (exclusive): at 0.5 the shortest unit would
#: see half the CE length, and the spread formula is defined for s < 0.5.
UNIT_LENGTH_SPREAD_MAX = 0.5
#: Largest random-order seed: NumPy's ``default_rng`` takes any non-negative
#: integer; this keeps it a ROS ``integer`` (int64).
SEED_MAX = 2**63 - 1
#: The fields of the recruitment curve, which maps pulse width to command
#: (with ``pw_max_s``): the stimulator side, not the muscle's dynamics.
CURVE_FIELDS = ('pw_max_s', 'recruitment_curve', 'pw_threshold_s', 'pw_scale_s')
#: The fields of the stimulator: the device's limits and how its pulses are
#: sent (trains, current). Like the curve, they act before the muscle, not on
#: its dynamics.
STIMULATOR_FIELDS = ('chronaxie_s', 'current_ref_a', 'frequency_hz', 'stimulator',
                     'burst_interval_s')
#: Most stimulation channels: more than any stimulator has (8 on the
#: RehaStim 2 and the P24); it only bounds the per-channel bookkeeping.
N_CHANNELS_MAX = 16


def finite_float(value: Any) -> float | None:
    """``float(value)`` if that is a finite number, else ``None``.

    Integers too large for a float (YAML reads ``1e400`` written without a
    point as an int) overflow rather than becoming inf; they count as not finite.
    """
    try:
        f = float(value)
    except (OverflowError, TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def check_instances(kind: type, values: Iterable[Any], name: str) -> tuple[Any, ...]:
    """``values`` as a tuple, checked to hold at least one item, each a ``kind``
    (the parameter list of a batch: muscles' parameters, limbs' plants).

    :param name: the argument's name, for the messages (``params``)
    :raises ValueError: naming the argument and, for a wrong item, its index and value
    """
    values = tuple(values)
    if not values:
        raise ValueError(f'`{name}` must hold at least one {kind.__name__}, got none')
    for i, value in enumerate(values):
        if not isinstance(value, kind):
            raise ValueError(f'`{name}[{i}]` must be a {kind.__name__}, got {value!r}')
    return values


def _float(name: str, value: Any, spec: Mapping[str, Any]) -> float:
    """One float parameter, validated against its field's range.

    Integers from YAML (``45`` for ``45.0``) are accepted as floats.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f'`{name}` must be a number, got {value!r}')
    number = finite_float(value)
    high_ok = (number is not None
               and (number <= spec['high'] if spec['high_inclusive'] else number < spec['high']))
    if number is not None and not high_ok:
        bound = 'at most' if spec['high_inclusive'] else 'below'
        raise ValueError(f'`{name}` must be {bound} {spec["high"]:g}, got {value!r}')
    if number is None or not _in_range(number, spec):
        raise ValueError(f'`{name}` must be {range_text(spec)}, got {value!r}')
    return number


def _float_array(name: str, value: Any, spec: Mapping[str, Any]) -> tuple[float, ...]:
    """A float-array parameter as a tuple, every entry validated.

    Accepts any sequence (a YAML list, a ROS ``double_array``, a NumPy array).
    """
    if isinstance(value, (str, bytes, Mapping)) or not hasattr(value, '__len__'):
        raise ValueError(f'`{name}` must be a list of numbers, got {value!r}')
    values = list(value)
    if not values:
        raise ValueError(f'`{name}` must have at least one entry, got {value!r}')
    out = []
    for i, v in enumerate(values):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f'`{name}[{i}]` must be a number, got {v!r}')
        number = finite_float(v)
        if number is None or not _in_range(number, spec):
            raise ValueError(f'`{name}[{i}]` must be {range_text(spec)}, got {v!r}')
        out.append(number)
    return tuple(out)


def rest_ratio_range() -> tuple[float, float]:
    """[-] the open range of l_rest / l_opt where FL >= :data:`MIN_FL_AT_REST`.

    The roots of FL(x) = MIN_FL_AT_REST, from the parabola's vertex.
    """
    x_peak = -FL_B / (2.0 * FL_A)
    fl_peak = FL_C - FL_B * FL_B / (4.0 * FL_A)
    half_width = math.sqrt((fl_peak - MIN_FL_AT_REST) / -FL_A)
    return x_peak - half_width, x_peak + half_width


def _spec(unit: str, description: str, *, low: float | None = None,
          high: float | None = None, choices: tuple[str, ...] | None = None,
          low_inclusive: bool = False, high_inclusive: bool = True,
          source: str = 'the paper') -> dict:
    """Field metadata: unit, words, range and where the default comes from.

    Floats (and every entry of a float array) must lie in the range ``low``
    to ``high``; ``low_inclusive`` and ``high_inclusive`` say whether the ends
    are accepted. Integers take the closed range.
    """
    return {'unit': unit, 'description': description, 'low': low, 'high': high,
            'choices': choices, 'low_inclusive': low_inclusive,
            'high_inclusive': high_inclusive, 'source': source}


def range_text(spec: Mapping[str, Any]) -> str:
    """The accepted range in words, e.g. ``in [0, 1e+12]`` or ``positive``."""
    if spec['low'] == 0.0 and not spec['low_inclusive'] and spec['high'] == _FLOAT_MAX:
        return 'positive and finite'
    left = '[' if spec['low_inclusive'] else '('
    right = ']' if spec['high_inclusive'] else ')'
    return f'in {left}{spec["low"]:g}, {spec["high"]:g}{right}'


def range_constraint(spec: Mapping[str, Any]) -> str:
    """The accepted range as a constraint, e.g. ``> 0 and <= 1e+12`` (descriptors)."""
    low = '>=' if spec['low_inclusive'] else '>'
    high = '<=' if spec['high_inclusive'] else '<'
    return f'{low} {spec["low"]:g} and {high} {spec["high"]:g}'


def _in_range(number: float, spec: Mapping[str, Any]) -> bool:
    low, high = spec['low'], spec['high']
    above = number >= low if spec['low_inclusive'] else number > low
    below = number <= high if spec['high_inclusive'] else number < high
    return above and below


@dataclass(frozen=True)
class MuscleParams:
    """Parameters of the multiple-motor-unit Hill-type muscle (doc/model.md section 5).

    Validated once, on construction; an invalid value raises ``ValueError``
    naming the field and the value.

    :param f_iso_max_n: [N] maximal isometric force (f_iso_max)
    :param k_se_n_per_m: [N/m] series elastic stiffness (k_SE)
    :param k_pe_n_per_m: [N/m] parallel elastic stiffness (k_PE)
    :param l_rest_m: [m] CE length in the resting state (l_rest)
    :param l_opt_m: [m] CE optimal length (l_opt)
    :param fv_a_n: [N] concentric Hill constant (a)
    :param fv_b_m_per_s: [m/s] concentric Hill constant (b)
    :param fv_a_ecc_n: [N] eccentric constant (a')
    :param fv_b_ecc_m_per_s: [m/s] eccentric constant (b')
    :param n_units: [-] number of virtual motor units (N)
    :param units: ``multi`` (N units, Eq. 2) or ``single`` (one unit)
    :param length: ``initial`` (length at recruitment) or ``instantaneous``
    :param pw_max_s: [s] pulse width that recruits every unit (PW_max)
    """

    f_iso_max_n: float = field(default=45.0, metadata=_spec(
        'N', 'maximal isometric force f_iso_max', low=0.0, high=_FLOAT_MAX))
    k_se_n_per_m: float = field(default=10000.0, metadata=_spec(
        'N/m', 'series elastic (tendon) stiffness k_SE', low=0.0, high=_FLOAT_MAX))
    k_pe_n_per_m: float = field(default=1000.0, metadata=_spec(
        'N/m', 'parallel elastic stiffness k_PE', low=0.0, high=_FLOAT_MAX))
    l_rest_m: float = field(default=0.125, metadata=_spec(
        'm', 'CE length at rest l_rest', low=0.0, high=_FLOAT_MAX))
    l_opt_m: float = field(default=0.100, metadata=_spec(
        'm', 'CE optimal length l_opt', low=0.0, high=_FLOAT_MAX))
    fv_a_n: float = field(default=10.0, metadata=_spec(
        'N', 'concentric Hill constant a', low=0.0, high=_FLOAT_MAX))
    fv_b_m_per_s: float = field(default=0.040, metadata=_spec(
        'm/s', 'concentric Hill constant b', low=0.0, high=_FLOAT_MAX))
    fv_a_ecc_n: float = field(default=10.0, metadata=_spec(
        'N', "eccentric constant a'", low=0.0, high=_FLOAT_MAX))
    fv_b_ecc_m_per_s: float = field(default=0.030, metadata=_spec(
        'm/s', "eccentric constant b'", low=0.0, high=_FLOAT_MAX))
    n_units: int = field(default=1000, metadata=_spec(
        '-', 'number of virtual motor units N', low=1, high=N_UNITS_MAX))
    units: str = field(default='multi', metadata=_spec(
        '-', 'motor units: multi (N units, Eq. 2) or single', choices=UNITS_CHOICES))
    length: str = field(default='initial', metadata=_spec(
        '-', 'length in FL: initial (at recruitment) or instantaneous',
        choices=LENGTH_CHOICES))
    pw_max_s: float = field(default=0.0005, metadata=_spec(
        's', 'pulse width that recruits every unit PW_max', low=0.0, high=_FLOAT_MAX))

    # -- FES extensions (doc/model.md section 7). Every default switches its
    # feature off, so that the defaults are exactly the paper's model.
    recruitment_curve: str = field(default='linear', metadata=_spec(
        '-', 'pulse width to recruitment command u: linear (PW / PW_max), '
        'threshold_linear (Veltink 1992) or exponential (Ding et al. 2007)',
        choices=RECRUITMENT_CURVE_CHOICES))
    pw_threshold_s: float = field(default=0.0, metadata=_spec(
        's', 'pulse width below which nothing is recruited PW_th', low=0.0,
        high=_FLOAT_MAX, low_inclusive=True))
    # 194.1 us: pdt of Ding et al. 2007 (Muscle & Nerve 36(2): 214-222), as in
    # cocofest's ding2007 model; only the exponential curve uses it.
    pw_scale_s: float = field(default=194.1e-6, metadata=_spec(
        's', 'pulse-width scale of the exponential curve PW_scale', low=0.0,
        high=_FLOAT_MAX, source='Ding et al. 2007 (pdt)'))
    emd_s: float = field(default=0.0, metadata=_spec(
        's', 'electromechanical delay of the command', low=0.0, high=_FLOAT_MAX,
        low_inclusive=True))
    tau_act_s: float = field(default=0.0, metadata=_spec(
        's', 'activation time constant (0: instantaneous)', low=0.0, high=_FLOAT_MAX,
        low_inclusive=True))
    tau_deact_s: float = field(default=0.0, metadata=_spec(
        's', 'deactivation time constant (0: instantaneous)', low=0.0, high=_FLOAT_MAX,
        low_inclusive=True))
    fv_scaling: str = field(default='absolute', metadata=_spec(
        '-', "force-velocity constants a, a': absolute (newtons, the paper) or relative "
        '(scaled by Eff.f_iso / f_iso_max)', choices=FV_SCALING_CHOICES))
    fatigue: str = field(default='none', metadata=_spec(
        '-', 'fatigue law: none or riener (per unit in multi, whole muscle in single)',
        choices=FATIGUE_CHOICES))
    # Riener's law (Riener 1998) as written in cocofest (veltink1992_and_riener1998.py):
    # mu_min 0.2, T_fat 30 s, T_rec 50 s. One entry per fibre type; one entry
    # applies to every type.
    fatigue_min: tuple[float, ...] = field(default=(0.2,), metadata=_spec(
        '-', 'fitness of a fully fatigued unit mu_min, per fibre type', low=0.0, high=1.0,
        low_inclusive=True, source='Riener 1998 as in cocofest'))
    tau_fatigue_s: tuple[float, ...] = field(default=(30.0,), metadata=_spec(
        's', 'fatigue time constant of a recruited unit T_fat, per fibre type', low=0.0,
        high=_FLOAT_MAX, source='Riener 1998 as in cocofest'))
    tau_recovery_s: tuple[float, ...] = field(default=(50.0,), metadata=_spec(
        's', 'recovery time constant of a resting unit T_rec, per fibre type', low=0.0,
        high=_FLOAT_MAX, source='Riener 1998 as in cocofest'))
    fibre_fractions: tuple[float, ...] = field(default=(1.0,), metadata=_spec(
        '-', 'share of the units of each fibre type (normalised by their sum)', low=0.0,
        high=_FLOAT_MAX, low_inclusive=True))
    fibre_force_weights: tuple[float, ...] = field(default=(1.0,), metadata=_spec(
        '-', 'relative maximal force of one unit of each fibre type', low=0.0,
        high=_FLOAT_MAX))
    recruitment_order: str = field(default='size', metadata=_spec(
        '-', 'order in which units are recruited: size (unit 1 first), reverse (types '
        'reversed) or random (seeded permutation)', choices=RECRUITMENT_ORDER_CHOICES))
    recruitment_seed: int = field(default=0, metadata=_spec(
        '-', 'seed of the random recruitment order', low=0, high=SEED_MAX))
    unit_length_spread: float = field(default=0.0, metadata=_spec(
        '-', 'half-width s of the per-unit CE length scale 1 - s .. 1 + s', low=0.0,
        high=UNIT_LENGTH_SPREAD_MAX, low_inclusive=True, high_inclusive=False))

    # -- Pulses as a stimulator delivers them (doc/model.md section 10).
    activation_model: str = field(default='first_order', metadata=_spec(
        '-', 'activation: first_order (a level command through the delay and a first-order '
        'law) or ding2003 (pulses through Ding et al. 2003\'s CN and force dynamics, per '
        'channel)', choices=ACTIVATION_MODEL_CHOICES))
    channel_fractions: tuple[float, ...] = field(default=(1.0,), metadata=_spec(
        '-', 'share of the units of each stimulation channel (normalised by their sum)',
        low=0.0, high=_FLOAT_MAX, low_inclusive=True))
    channel_seed: int = field(default=1, metadata=_spec(
        '-', 'seed of the permutation that gives each channel its territory of units',
        low=0, high=SEED_MAX))
    # 459 us: the mean strength-duration time constant of human motor axons,
    # Mogyoros, Kiernan & Burke 1996 (Brain 119: 439-447); doc/model.md section 10.
    chronaxie_s: float = field(default=DEFAULT_CHRONAXIE_S, metadata=_spec(
        's', 'chronaxie c of the strength-duration law I PW / (PW + c) >= rheobase',
        low=0.0, high=_FLOAT_MAX, source='Mogyoros, Kiernan & Burke 1996'))
    # 40 mA: the constant current of pulse-width-modulated quadriceps FES
    # (IFESS 2016 spatially distributed sequential stimulation study); doc/model.md section 10.
    current_ref_a: float = field(default=DEFAULT_CURRENT_REF_A, metadata=_spec(
        'A', 'current I_ref at which the recruitment curve in pulse width holds', low=0.0,
        high=_FLOAT_MAX, source='IFESS 2016 quadriceps SDSS study'))
    # Ding, Wexler & Binder-Macleod 2003 (J Electromyogr Kinesiol 13(6): 575-588)
    # as written in cocofest's ding2003.py: tau_c 20 ms, tau1 50.957 ms,
    # tau2 60 ms, Km 0.103, R0 = Km + 1.04; doc/model.md section 10.5.
    ding_tau_c_s: float = field(default=0.020, metadata=_spec(
        's', 'time constant of the Ca2+-troponin complex formation tau_c (Ding 2003)',
        low=0.0, high=_FLOAT_MAX, source='Ding et al. 2003 as in cocofest'))
    ding_tau1_s: float = field(default=0.050957, metadata=_spec(
        's', 'force decline time constant without cross-bridges tau1 (Ding 2003)', low=0.0,
        high=_FLOAT_MAX, source='Ding et al. 2003 as in cocofest'))
    ding_tau2_s: float = field(default=0.060, metadata=_spec(
        's', 'force decline time constant due to cross-bridge friction tau2 (Ding 2003)',
        low=0.0, high=_FLOAT_MAX, low_inclusive=True, source='Ding et al. 2003 as in cocofest'))
    ding_km: float = field(default=0.103, metadata=_spec(
        '-', 'sensitivity of strongly bound cross-bridges to CN, Km (Ding 2003)', low=0.0,
        high=_FLOAT_MAX, source='Ding et al. 2003 as in cocofest'))
    ding_r0_offset: float = field(default=1.04, metadata=_spec(
        '-', 'R0 - Km: the enhancement of CN by a closely following pulse (Ding 2003)',
        low=0.0, high=_FLOAT_MAX, low_inclusive=True, source='Ding et al. 2003 as in cocofest'))
    # 1e-4 of the force at infinite frequency: far below any force a sensor
    # reads (0.03 N of 334 N), so releasing the units there changes no output.
    release_activation: float = field(default=1e-4, metadata=_spec(
        '-', 'activation below which a channel with no pulse for 1 s releases its units',
        low=0.0, high=1.0, high_inclusive=False))
    # 30 Hz: a common FES frequency for the quadriceps (Kesar & Binder-Macleod
    # 2006's 30 Hz protocol; 20-50 Hz in most FES cycling and standing systems).
    frequency_hz: float = field(default=30.0, metadata=_spec(
        'Hz', 'frequency of the pulses the plain pulse_width input sends on channel 1 '
        '(ding2003)', low=0.0, high=_FLOAT_MAX, source='Kesar & Binder-Macleod 2006'))
    stimulator: str = field(default='generic', metadata=_spec(
        '-', 'stimulator whose limits commands are checked against: generic, rehastim2 or '
        'p24 (pyScienceMode 1.1.5)', choices=STIMULATOR_CHOICES))
    # 5 ms: the catch-like doublet of Binder-Macleod's trains (Bickel et al. 2004).
    burst_interval_s: float = field(default=0.005, metadata=_spec(
        's', 'interval between the pulses of a doublet or triplet', low=0.0, high=_FLOAT_MAX,
        source='Bickel et al. 2004'))

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            spec = f.metadata
            if spec['choices'] is not None:
                if value not in spec['choices']:
                    raise ValueError(
                        f'`{f.name}` must be one of {", ".join(spec["choices"])}, '
                        f'got {value!r}')
            elif f.type == 'int':
                if isinstance(value, bool) or not isinstance(value, int):
                    raise ValueError(f'`{f.name}` must be an integer, got {value!r}')
                if not spec['low'] <= value <= spec['high']:
                    raise ValueError(
                        f'`{f.name}` must be in [{spec["low"]}, {spec["high"]}], '
                        f'got {value!r}')
            elif f.type.startswith('tuple'):
                object.__setattr__(self, f.name, _float_array(f.name, value, spec))
            else:
                object.__setattr__(self, f.name, _float(f.name, value, spec))
        self._check_rest_length_makes_force()
        self._check_fes_combinations()
        self._check_pulse_combinations()

    @property
    def n_fibre_types(self) -> int:
        """[-] number of fibre types K (entries of ``fibre_fractions``)."""
        return len(self.fibre_fractions)

    def per_type(self, name: str) -> tuple[float, ...]:
        """A per-fibre-type array with a single entry repeated for every type.

        :param name: ``fatigue_min``, ``tau_fatigue_s``, ``tau_recovery_s`` or
            ``fibre_force_weights``
        :return: K values, one per fibre type
        """
        values = getattr(self, name)
        return values * self.n_fibre_types if len(values) == 1 else values

    @property
    def fes_defaults(self) -> bool:
        """True if every FES extension of the muscle's dynamics is off: the
        paper's model exactly.

        The recruitment curve is not part of it: it maps a pulse width to the
        command before the muscle (:mod:`.stimulus`), and a muscle given the
        command behaves the same whatever the curve.
        """
        return all(getattr(self, n) == f.default for n, f in _FES_FIELDS.items()
                   if n not in CURVE_FIELDS and n not in STIMULATOR_FIELDS)

    def _check_shares(self, name: str, most: int) -> None:
        """Shares of the units (fibre types, channels): at most ``most`` entries
        with a positive sum.

        :raises ValueError: naming the field and its value
        """
        shares = getattr(self, name)
        if len(shares) > most:
            raise ValueError(f'`{name}` must have at most {most} entries, got {len(shares)}')
        if not sum(shares) > 0.0:
            raise ValueError(f'`{name}` must have a positive sum, got {list(shares)!r}')

    def _check_fes_combinations(self) -> None:
        """Checks across fields of the FES extensions (doc/model.md section 7).

        :raises ValueError: naming the fields and their values
        """
        k = self.n_fibre_types
        self._check_shares('fibre_fractions', N_FIBRE_TYPES_MAX)
        for name in ('fibre_force_weights', 'fatigue_min', 'tau_fatigue_s',
                     'tau_recovery_s'):
            n = len(getattr(self, name))
            if n not in (1, k):
                raise ValueError(
                    f'`{name}` must have 1 entry or one per fibre type ({k}, as '
                    f'`fibre_fractions`), got {n}: {list(getattr(self, name))!r}')
        if (self.recruitment_curve == 'threshold_linear'
                and not self.pw_threshold_s < self.pw_max_s):
            raise ValueError(
                '`pw_threshold_s` must be below `pw_max_s` for the threshold_linear curve, '
                f'got pw_threshold_s = {self.pw_threshold_s!r} >= pw_max_s = '
                f'{self.pw_max_s!r}')
        if self.units == 'single':
            if k != 1:
                raise ValueError(
                    '`fibre_fractions` must have a single entry with `units: single` '
                    f'(one unit has one fibre type), got {list(self.fibre_fractions)!r}')
            if self.unit_length_spread != 0.0:
                raise ValueError(
                    '`unit_length_spread` must be 0 with `units: single` (one unit has no '
                    f'spread of lengths), got {self.unit_length_spread!r}')
            for name in ('fibre_force_weights', 'fatigue_min', 'tau_fatigue_s',
                         'tau_recovery_s'):
                if len(getattr(self, name)) != 1:
                    raise ValueError(f'`{name}` must have a single entry with `units: '
                                     f'single`, got {list(getattr(self, name))!r}')

    def _check_pulse_combinations(self) -> None:
        """Checks across the fields of pulses and channels (doc/model.md section 10).

        :raises ValueError: naming the fields and their values
        """
        c = self.n_channels
        self._check_shares('channel_fractions', N_CHANNELS_MAX)
        if self.activation_model == 'first_order':
            if c != 1:
                raise ValueError(
                    '`channel_fractions` must have a single entry with `activation_model: '
                    'first_order` (a level command drives the whole muscle; channels need '
                    f'ding2003), got {list(self.channel_fractions)!r}')
            return
        if self.units != 'multi':
            raise ValueError('`units` must be multi with `activation_model: ding2003` (each '
                             f'channel recruits units of its own territory), got {self.units!r}')
        for name in ('tau_act_s', 'tau_deact_s'):
            if getattr(self, name) != 0.0:
                raise ValueError(
                    f'`{name}` must be 0 with `activation_model: ding2003` (Ding\'s CN and '
                    f'force dynamics are the activation), got {getattr(self, name)!r}')
        if self.n_units < c:
            raise ValueError(f'`n_units` must be at least the number of channels ({c}), '
                             f'got {self.n_units!r}')
        # A channel without units would take pulses and move nothing, and its
        # pool's mean fitness is 0/0: refused, as a territory the user asked for.
        ends = type_block_ends(self.n_units, self.channel_fractions)
        for channel, (start, end) in enumerate(zip([0] + ends[:-1], ends), start=1):
            if end == start:
                raise ValueError(
                    f'`channel_fractions` must give every channel at least one of the '
                    f'{self.n_units} units (`n_units`), got {list(self.channel_fractions)!r}: '
                    f'channel {channel} gets none')

    @property
    def n_channels(self) -> int:
        """[-] number of stimulation channels C (entries of ``channel_fractions``)."""
        return len(self.channel_fractions)

    def _check_rest_length_makes_force(self) -> None:
        """Reject l_rest / l_opt where FL is below :data:`MIN_FL_AT_REST`.

        :raises ValueError: naming both parameters, their values and the range
        """
        x = self.l_rest_m / self.l_opt_m
        fl = (FL_A * x + FL_B) * x + FL_C
        if fl < MIN_FL_AT_REST:
            low, high = rest_ratio_range()
            raise ValueError(
                f'`l_rest_m` / `l_opt_m` must be in ({low:.4f}, {high:.4f}), where the '
                f'force-length relation gives at least {MIN_FL_AT_REST:g} of f_iso_max at '
                f'rest length, got l_rest_m = {self.l_rest_m!r} / l_opt_m = '
                f'{self.l_opt_m!r} = {x:.6g} (FL = {max(fl, 0.0):.6g})')

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Names of all parameters, in declaration order."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, source: str = 'parameters',
                     ignore: tuple[str, ...] = ()) -> 'MuscleParams':
        """Build parameters from a mapping such as a YAML section.

        Missing keys take the paper's defaults.

        :param values: parameter name to value
        :param source: what the mapping came from, for error messages
        :param ignore: keys that are known but are not muscle parameters
            (such as the simulator node's ``rate_hz``)
        :raises ValueError: on an unknown key or an invalid value
        """
        if not isinstance(values, Mapping):
            raise ValueError(f'{source}: expected a mapping of parameter names to '
                             f'values, got {values!r}')
        known = set(cls.field_names())
        unknown = sorted(str(k) for k in values if k not in known and k not in ignore)
        if unknown:
            raise ValueError(f'{source}: unknown parameter `{unknown[0]}` '
                             f'(known: {", ".join(cls.field_names())})')
        try:
            return cls(**{k: v for k, v in values.items() if k in known})
        except ValueError as err:
            raise ValueError(f'{source}: {err}') from None

    def replace(self, **changes: Any) -> 'MuscleParams':
        """A copy with some fields changed, validated like a new instance."""
        return dataclasses.replace(self, **changes)


#: The FES extensions' fields (all declared after ``pw_max_s``), by name.
_FES_FIELDS = {f.name: f for f in dataclasses.fields(MuscleParams)[
    MuscleParams.field_names().index('pw_max_s') + 1:]}
