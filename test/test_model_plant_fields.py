"""A limb plant's parameters by dotted name (model/plant_fields.py): resolving a
name, its messages, reading a value and replacing values."""
import dataclasses
import math

import pytest

from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.model.limb import JointParams, LimbMuscle, LimbPlant
from hill_muscle_ros.model.plant_fields import (GEOMETRY, JOINT, PARAMS, PlantNameError,
                                                plant_field, plant_value, replaced_plant)

PARTS = '(parts: joint, quad, ham)'


def _plant() -> LimbPlant:
    return LimbPlant(JointParams(name='knee', damping_n_m_s_per_rad=0.5),
                     (LimbMuscle('quad', 'extensor', 0.04, 0.1, MuscleParams(f_iso_max_n=900.0)),
                      LimbMuscle('ham', 'flexor', 0.03, -0.2, MuscleParams(f_iso_max_n=700.0))))


def _message(name: str, label: str = '') -> str:
    """The message of the PlantNameError that resolving ``name`` raises."""
    with pytest.raises(PlantNameError) as err:
        plant_field(name, _plant(), label)
    return str(err.value)


# --------------------------------------------------------------------------- resolving

def test_joint_name_resolves_to_the_joint_field_with_its_unit_and_range():
    p = plant_field('joint.mass_kg', _plant())
    assert (p.part, p.where, p.field, p.name) == ('joint', JOINT, 'mass_kg', 'joint.mass_kg')
    spec = {f.name: f for f in dataclasses.fields(JointParams)}['mass_kg'].metadata
    assert (p.unit, p.low, p.high) == ('kg', spec['low'], spec['high'])


def test_moment_arm_resolves_to_the_muscle_geometry_in_zero_to_one_metre():
    p = plant_field('ham.moment_arm_m', _plant())
    assert (p.part, p.where, p.field) == ('ham', GEOMETRY, 'moment_arm_m')
    assert (p.unit, p.low, p.high) == ('m', 0.0, 1.0)


def test_reference_angle_range_is_two_turns_either_way():
    p = plant_field('quad.reference_angle_rad', _plant())
    assert (p.unit, p.low, p.high) == ('rad', -4.0 * math.pi, 4.0 * math.pi)


def test_muscle_parameter_resolves_to_the_muscle_params_field():
    p = plant_field('quad.k_se_n_per_m', _plant())
    assert (p.part, p.where, p.field, p.unit) == ('quad', PARAMS, 'k_se_n_per_m', 'N/m')


def test_name_without_a_part_is_an_error_naming_it_and_the_parts():
    message = _message('f_iso_max_n')
    assert message.startswith('`f_iso_max_n`: on a limb, name the joint or the muscle')
    assert message.endswith(PARTS)


def test_name_with_an_empty_field_is_an_error():
    assert 'name the joint or the muscle first' in _message('quad.')


def test_unknown_part_is_an_error_naming_the_part_and_the_parts():
    assert _message('soleus.f_iso_max_n') == ('`soleus.f_iso_max_n`: the plant has no joint '
                                              f'or muscle `soleus` {PARTS}')


def test_unknown_joint_field_is_an_error_listing_the_joint_fields():
    known = ', '.join(f'joint.{f.name}' for f in dataclasses.fields(JointParams)[1:])
    assert (_message('joint.stiffness')
            == f'unknown parameter `joint.stiffness` of the joint (known: {known})')


def test_joint_name_field_is_not_a_parameter():
    assert _message('joint.name').startswith('unknown parameter `joint.name` of the joint')


def test_unknown_muscle_field_is_an_error_listing_geometry_then_muscle_params():
    known = ', '.join(['moment_arm_m', 'reference_angle_rad', *MuscleParams.field_names()])
    assert (_message('quad.f_iso')
            == f'unknown parameter `quad.f_iso` of muscle `quad` (known: {known})')


def test_muscle_action_is_not_a_parameter():
    assert _message('quad.action').startswith('unknown parameter `quad.action` of muscle')


def test_label_precedes_the_name_in_the_message():
    assert _message('joint.x', 'vary.').startswith('unknown parameter `vary.joint.x` of the joint')


def test_plant_name_error_is_a_value_error():
    assert issubclass(PlantNameError, ValueError)


# --------------------------------------------------------------------------- values

@pytest.mark.parametrize('name, expected', [
    ('joint.damping_n_m_s_per_rad', 0.5),
    ('ham.moment_arm_m', 0.03),
    ('ham.reference_angle_rad', -0.2),
    ('quad.f_iso_max_n', 900.0),
    ('ham.f_iso_max_n', 700.0),
])
def test_plant_value_reads_the_named_value(name, expected):
    assert plant_value(_plant(), name) == expected


def test_plant_value_of_a_list_field_is_the_tuple():
    assert plant_value(_plant(), 'quad.tau_fatigue_s') == MuscleParams().tau_fatigue_s


def test_replaced_plant_changes_only_the_named_values():
    base = _plant()
    new = replaced_plant(base, {'joint.mass_kg': 5.0, 'ham.moment_arm_m': 0.05,
                                'ham.f_iso_max_n': 800.0})
    assert new.joint == dataclasses.replace(base.joint, mass_kg=5.0)
    assert new.muscles[0] == base.muscles[0]
    assert new.muscles[1] == dataclasses.replace(
        base.muscles[1], moment_arm_m=0.05,
        params=dataclasses.replace(base.muscles[1].params, f_iso_max_n=800.0))


def test_replaced_plant_without_changes_equals_the_base():
    assert replaced_plant(_plant(), {}) == _plant()


def test_replaced_plant_leaves_the_base_unchanged():
    base = _plant()
    replaced_plant(base, {'quad.f_iso_max_n': 1.0})
    assert base == _plant()


def test_replaced_plant_validates_a_muscle_parameter():
    with pytest.raises(ValueError, match='`f_iso_max_n` must be positive and finite, got -3.0'):
        replaced_plant(_plant(), {'quad.f_iso_max_n': -3.0})


def test_replaced_plant_validates_the_geometry():
    with pytest.raises(ValueError, match=r'`ham.moment_arm_m` must be in \(0, 1\] m, got 2.0'):
        replaced_plant(_plant(), {'ham.moment_arm_m': 2.0})


def test_replaced_plant_validates_the_joint():
    with pytest.raises(ValueError, match='`joint.inertia_kg_m2` must be'):
        replaced_plant(_plant(), {'joint.inertia_kg_m2': 0.0})


def test_replaced_plant_refuses_an_unknown_name():
    with pytest.raises(PlantNameError, match='the plant has no joint or muscle `soleus`'):
        replaced_plant(_plant(), {'soleus.f_iso_max_n': 1.0})
