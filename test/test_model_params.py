"""Parameters: the paper's SI defaults, and validation that names the field."""
import dataclasses
import math

import numpy as np
import pytest

from hill_muscle_ros.model import MuscleParams, force_length
from hill_muscle_ros.model.params import _FLOAT_MAX as MAX_FLOAT
from hill_muscle_ros.model.params import MIN_FL_AT_REST, rest_ratio_range

FLOAT_FIELDS = [f.name for f in dataclasses.fields(MuscleParams)
                if f.type == 'float']
#: Floats that must be positive; the others (delays, time constants that may
#: be 0 for "instantaneous", the length spread) accept zero.
POSITIVE_FIELDS = [f.name for f in dataclasses.fields(MuscleParams)
                   if f.type == 'float' and not f.metadata['low_inclusive']
                   and f.metadata['high'] == MAX_FLOAT]
NON_NEGATIVE_FIELDS = [f.name for f in dataclasses.fields(MuscleParams)
                       if f.type == 'float' and f.metadata['low_inclusive']]


def test_defaults_are_the_papers_values_in_si():
    p = MuscleParams()
    assert (p.f_iso_max_n, p.k_se_n_per_m, p.k_pe_n_per_m) == (45.0, 10000.0, 1000.0)
    assert (p.l_rest_m, p.l_opt_m) == (0.125, 0.100)
    assert (p.fv_a_n, p.fv_b_m_per_s, p.fv_a_ecc_n, p.fv_b_ecc_m_per_s) == \
        (10.0, 0.040, 10.0, 0.030)
    assert (p.n_units, p.units, p.length, p.pw_max_s) == (1000, 'multi', 'initial', 0.0005)


def test_field_names_are_the_documented_keys():
    assert MuscleParams.field_names() == (
        'f_iso_max_n', 'k_se_n_per_m', 'k_pe_n_per_m', 'l_rest_m', 'l_opt_m', 'fv_a_n',
        'fv_b_m_per_s', 'fv_a_ecc_n', 'fv_b_ecc_m_per_s', 'n_units', 'units', 'length',
        'pw_max_s',
        # The FES extensions.
        'recruitment_curve', 'pw_threshold_s', 'pw_scale_s', 'emd_s', 'tau_act_s',
        'tau_deact_s', 'fv_scaling', 'fatigue', 'fatigue_min', 'tau_fatigue_s',
        'tau_recovery_s', 'fibre_fractions', 'fibre_force_weights', 'recruitment_order',
        'recruitment_seed', 'unit_length_spread',
        # Pulses, channels and the stimulator.
        'activation_model', 'channel_fractions', 'channel_seed', 'chronaxie_s',
        'current_ref_a', 'ding_tau_c_s', 'ding_tau1_s', 'ding_tau2_s', 'ding_km',
        'ding_r0_offset', 'release_activation', 'frequency_hz', 'stimulator',
        'burst_interval_s')


def test_fes_defaults_switch_every_extension_off():
    p = MuscleParams()
    assert p.fes_defaults
    assert (p.recruitment_curve, p.emd_s, p.tau_act_s, p.tau_deact_s) == ('linear', 0, 0, 0)
    assert (p.fv_scaling, p.fatigue, p.recruitment_order) == ('absolute', 'none', 'size')
    assert (p.fibre_fractions, p.unit_length_spread) == ((1.0,), 0.0)
    assert not p.replace(tau_act_s=0.01).fes_defaults


@pytest.mark.parametrize('bad', [0.0, 1.0, -0.1, math.nan, math.inf])
def test_release_activation_is_a_fraction_strictly_between_0_and_1(bad):
    with pytest.raises(ValueError, match=f'`release_activation` must be (in \\(0, 1\\)|below 1), '
                                         f'got {bad!r}'):
        MuscleParams(release_activation=bad)


def test_parameters_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        MuscleParams().k_se_n_per_m = 1.0


@pytest.mark.parametrize('name', POSITIVE_FIELDS)
@pytest.mark.parametrize('bad', [-3.0, 0.0, math.nan, math.inf, -math.inf])
def test_non_positive_or_non_finite_number_is_rejected_by_name(name, bad):
    with pytest.raises(ValueError, match=f'`{name}` must be positive and finite, got {bad!r}'):
        MuscleParams(**{name: bad})


@pytest.mark.parametrize('name', NON_NEGATIVE_FIELDS)
@pytest.mark.parametrize('bad', [-3.0, math.nan, -math.inf])
def test_negative_or_nan_delay_time_constant_or_spread_is_rejected_by_name(name, bad):
    with pytest.raises(ValueError, match=f'`{name}` must be in \\[0, .*got {bad!r}'):
        MuscleParams(**{name: bad})


@pytest.mark.parametrize('name', NON_NEGATIVE_FIELDS)
def test_zero_switches_a_non_negative_feature_off_and_is_accepted(name):
    assert getattr(MuscleParams(**{name: 0}), name) == 0.0


@pytest.mark.parametrize('name', FLOAT_FIELDS)
def test_non_number_is_rejected_by_name(name):
    with pytest.raises(ValueError, match=f'`{name}` must be a number'):
        MuscleParams(**{name: 'stiff'})
    with pytest.raises(ValueError, match=f'`{name}` must be a number'):
        MuscleParams(**{name: True})


def test_integer_value_for_a_float_field_becomes_a_float():
    p = MuscleParams(f_iso_max_n=45)
    assert p.f_iso_max_n == 45.0 and isinstance(p.f_iso_max_n, float)


@pytest.mark.parametrize('bad', [0, -1])
def test_fewer_than_one_unit_is_rejected(bad):
    with pytest.raises(ValueError, match=rf'`n_units` must be in \[1, .*got {bad}'):
        MuscleParams(n_units=bad)


@pytest.mark.parametrize('bad', [1000.0, '1000', True])
def test_non_integer_unit_count_is_rejected(bad):
    with pytest.raises(ValueError, match='`n_units` must be an integer'):
        MuscleParams(n_units=bad)


def test_unknown_units_value_is_rejected():
    with pytest.raises(ValueError, match="`units` must be one of multi, single, got 'many'"):
        MuscleParams(units='many')


def test_unknown_length_value_is_rejected():
    with pytest.raises(ValueError,
                       match="`length` must be one of initial, instantaneous, got 'current'"):
        MuscleParams(length='current')


def test_unknown_key_in_a_mapping_is_rejected_by_name():
    with pytest.raises(ValueError, match='muscle.yaml: unknown parameter `k_se`'):
        MuscleParams.from_mapping({'k_se': 3.0}, source='muscle.yaml')


def test_mapping_error_names_the_source_and_field():
    with pytest.raises(ValueError, match='muscle.yaml: `k_se_n_per_m` must be positive'):
        MuscleParams.from_mapping({'k_se_n_per_m': -3.0}, source='muscle.yaml')


def test_mapping_may_carry_known_non_muscle_keys():
    p = MuscleParams.from_mapping({'rate_hz': 500, 'units': 'single'}, ignore=('rate_hz',))
    assert p.units == 'single'


def test_replace_validates_like_construction():
    with pytest.raises(ValueError, match='`l_opt_m`'):
        MuscleParams().replace(l_opt_m=-0.1)


def test_integer_too_large_for_a_float_is_rejected_by_name():
    with pytest.raises(ValueError, match='`k_se_n_per_m` must be positive and finite'):
        MuscleParams(k_se_n_per_m=10 ** 400)


def test_float_above_the_descriptor_bound_is_rejected_by_name():
    with pytest.raises(ValueError,
                       match=r'`k_se_n_per_m` must be at most 1e\+12, got 10000000000000\.0'):
        MuscleParams(k_se_n_per_m=1e13)


#: The accepted range of l_rest / l_opt, from Eq. 1 written as 1 - 2.777 (x - 1)^2
#: (its vertex form): FL(x) = 0.01 at x = 1 -+ sqrt(0.99 / 2.777).
_RATIO_LOW = 1.0 - math.sqrt(0.99 / 2.777)
_RATIO_HIGH = 1.0 + math.sqrt(0.99 / 2.777)
#: [-] relative step across a bound of the ratio: far above rounding, far below
#: any physical difference.
_ACROSS = 1e-9


def test_optimal_length_that_leaves_no_force_at_rest_is_rejected_naming_both():
    # l_rest / l_opt = 125: far outside the force-length range.
    with pytest.raises(ValueError) as err:
        MuscleParams(l_opt_m=0.001)
    text = str(err.value)
    assert '`l_rest_m` / `l_opt_m`' in text
    assert 'l_rest_m = 0.125' in text and 'l_opt_m = 0.001' in text
    assert '= 125 (FL = 0)' in text


@pytest.mark.parametrize('ratio', [_RATIO_LOW * (1 + _ACROSS), _RATIO_HIGH * (1 - _ACROSS), 1.0,
                                   1.25])
def test_rest_length_inside_the_force_length_range_is_accepted(ratio):
    p = MuscleParams(l_rest_m=0.1 * ratio, l_opt_m=0.1)
    assert force_length(p.l_rest_m / p.l_opt_m) >= MIN_FL_AT_REST


@pytest.mark.parametrize('ratio', [_RATIO_LOW * (1 - _ACROSS), _RATIO_HIGH * (1 + _ACROSS), 0.3,
                                   1.6, 2.0])
def test_rest_length_outside_the_force_length_range_is_rejected(ratio):
    with pytest.raises(ValueError, match=r'`l_rest_m` / `l_opt_m` must be in \(0\.4029, '
                                         r'1\.5971\)'):
        MuscleParams(l_rest_m=0.1 * ratio, l_opt_m=0.1)


def test_rest_ratio_range_is_where_force_length_reaches_the_bound():
    low, high = rest_ratio_range()
    assert low == pytest.approx(_RATIO_LOW, rel=1e-12)
    assert high == pytest.approx(_RATIO_HIGH, rel=1e-12)
    assert MIN_FL_AT_REST == 0.01


def test_live_replace_of_one_length_is_checked_against_the_other():
    with pytest.raises(ValueError, match='l_rest_m = 0.125 / l_opt_m = 0.05'):
        MuscleParams().replace(l_opt_m=0.05)


# -- FES extensions ---------------------------------------------------------------


def test_fibre_arrays_accept_any_sequence_and_become_tuples_of_floats():
    p = MuscleParams(fibre_fractions=[1, 3], fibre_force_weights=np.array([1.0, 2.0]),
                     tau_fatigue_s=[20, 60])
    assert p.fibre_fractions == (1.0, 3.0) and p.tau_fatigue_s == (20.0, 60.0)
    assert p.fibre_force_weights == (1.0, 2.0)


def test_a_single_entry_applies_to_every_fibre_type():
    p = MuscleParams(fibre_fractions=[0.5, 0.5])
    assert p.per_type('fatigue_min') == (0.2, 0.2)
    assert p.per_type('fibre_force_weights') == (1.0, 1.0)


def test_per_type_array_of_another_length_is_rejected_by_name():
    with pytest.raises(ValueError, match=r'`tau_recovery_s` must have 1 entry or one per '
                                         r'fibre type \(2, .*got 3'):
        MuscleParams(fibre_fractions=[1, 1], tau_recovery_s=[1, 2, 3])


@pytest.mark.parametrize('bad', [[], 'fast', 3.0, {'a': 1}])
def test_fibre_fractions_that_are_not_a_list_of_numbers_are_rejected(bad):
    with pytest.raises(ValueError, match='`fibre_fractions`'):
        MuscleParams(fibre_fractions=bad)


def test_fractions_summing_to_zero_are_rejected():
    with pytest.raises(ValueError, match='`fibre_fractions` must have a positive sum'):
        MuscleParams(fibre_fractions=[0.0, 0.0])


@pytest.mark.parametrize('bad', [-0.1, math.nan, math.inf])
def test_a_bad_array_entry_is_named_with_its_index(bad):
    with pytest.raises(ValueError, match=r'`fibre_fractions\[1\]` must be in \[0'):
        MuscleParams(fibre_fractions=[1.0, bad])


def test_fatigue_min_above_one_is_rejected():
    with pytest.raises(ValueError, match=r'`fatigue_min\[0\]` must be in \[0, 1\]'):
        MuscleParams(fatigue_min=[1.2])


def test_threshold_at_or_above_pw_max_is_rejected_for_the_threshold_curve():
    with pytest.raises(ValueError, match='`pw_threshold_s` must be below `pw_max_s`'):
        MuscleParams(recruitment_curve='threshold_linear', pw_threshold_s=0.0005)
    # The exponential curve does not use pw_max_s, so no such bound applies.
    MuscleParams(recruitment_curve='exponential', pw_threshold_s=0.0005)


def test_fibre_types_or_length_spread_with_a_single_unit_are_rejected():
    with pytest.raises(ValueError, match='`fibre_fractions` must have a single entry'):
        MuscleParams(units='single', fibre_fractions=[1, 1])
    with pytest.raises(ValueError, match='`unit_length_spread` must be 0 with `units: single`'):
        MuscleParams(units='single', unit_length_spread=0.1)


def test_length_spread_of_one_half_or_more_is_rejected():
    with pytest.raises(ValueError, match=r'`unit_length_spread` must be below 0\.5'):
        MuscleParams(unit_length_spread=0.5)


@pytest.mark.parametrize('name,bad', [('recruitment_curve', 'sigmoid'),
                                      ('fatigue', 'xia'), ('fv_scaling', 'normalised'),
                                      ('recruitment_order', 'henneman')])
def test_unknown_choice_is_rejected_by_name(name, bad):
    with pytest.raises(ValueError, match=f'`{name}` must be one of'):
        MuscleParams(**{name: bad})
