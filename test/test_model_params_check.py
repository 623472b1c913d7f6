"""params.check_instances: the parameter-list check of the batches."""
import pytest

from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.model.params import check_instances


def test_items_of_the_kind_come_back_as_a_tuple_in_order():
    a, b = MuscleParams(f_iso_max_n=30.0), MuscleParams(f_iso_max_n=40.0)
    assert check_instances(MuscleParams, iter([a, b]), 'params') == (a, b)


def test_empty_list_is_an_error_naming_the_argument_and_the_kind():
    with pytest.raises(ValueError) as err:
        check_instances(MuscleParams, [], 'params')
    assert str(err.value) == '`params` must hold at least one MuscleParams, got none'


def test_wrong_item_is_an_error_naming_its_index_and_value():
    with pytest.raises(ValueError) as err:
        check_instances(MuscleParams, [MuscleParams(), {'f_iso_max_n': 30.0}], 'params')
    assert str(err.value) == "`params[1]` must be a MuscleParams, got {'f_iso_max_n': 30.0}"
