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
from typing import Any, Mapping

from .curves import FL_A, FL_B, FL_C

UNITS_CHOICES = ('multi', 'single')
LENGTH_CHOICES = ('initial', 'instantaneous')

#: Upper bound of every float parameter: far beyond any muscle, it only turns a
#: typo or an overflow-prone value (1e300 N/m) into an error. The model and
#: the ROS parameter descriptors use the same bound.
_FLOAT_MAX = 1.0e12
#: [-] Smallest normalised force FL(l_rest / l_opt) accepted at rest length.
#: FL (curves.py, Eq. 1) is 1 - 2.777 (x - 1)^2: zero for |x - 1| >= 0.6. A
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


def rest_ratio_range() -> tuple[float, float]:
    """[-] the open range of l_rest / l_opt where FL >= :data:`MIN_FL_AT_REST`.

    The roots of FL(x) = MIN_FL_AT_REST, from the parabola's vertex.
    """
    x_peak = -FL_B / (2.0 * FL_A)
    fl_peak = FL_C - FL_B * FL_B / (4.0 * FL_A)
    half_width = math.sqrt((fl_peak - MIN_FL_AT_REST) / -FL_A)
    return x_peak - half_width, x_peak + half_width


def _spec(unit: str, description: str, *, low: float | None = None,
          high: float | None = None, choices: tuple[str, ...] | None = None) -> dict:
    return {'unit': unit, 'description': description, 'low': low, 'high': high,
            'choices': choices}


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
            else:
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise ValueError(f'`{f.name}` must be a number, got {value!r}')
                number = finite_float(value)
                if number is None or number <= 0.0:
                    raise ValueError(f'`{f.name}` must be positive and finite, '
                                     f'got {value!r}')
                if number > spec['high']:
                    raise ValueError(f'`{f.name}` must be at most {spec["high"]:g}, '
                                     f'got {value!r}')
                # Integers from YAML (``45`` for ``45.0``) are accepted as floats.
                object.__setattr__(self, f.name, number)
        self._check_rest_length_makes_force()

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
