"""``pytest -n auto``: how many workers test/conftest.py asks xdist for, and
that with one ROS worker the ROS modules run one at a time."""
import pytest

import conftest
from conftest import WORKERS_ENV, auto_workers, joining_workers, ros_workers


def test_the_environment_variable_sets_the_number_of_workers(monkeypatch):
    monkeypatch.setenv(WORKERS_ENV, '3')
    assert auto_workers() == (3, f'{WORKERS_ENV}=3')


@pytest.mark.parametrize('value, needle', [('x', "got 'x'"), ('2.5', "got '2.5'"),
                                           ('-1', 'must be 0 or more, got -1')])
def test_a_bad_number_of_workers_is_a_usage_error_naming_it(monkeypatch, value, needle):
    monkeypatch.setenv(WORKERS_ENV, value)
    with pytest.raises(pytest.UsageError, match=WORKERS_ENV) as err:
        auto_workers()
    assert needle in str(err.value)


def test_one_cpu_runs_serially(monkeypatch):
    monkeypatch.delenv(WORKERS_ENV, raising=False)
    monkeypatch.setattr(conftest.os, 'sched_getaffinity', lambda pid: {0})
    assert auto_workers() == (0, 'serial: 1 CPU')


def test_without_a_cpu_cgroup_tree_it_runs_serially_and_says_why(monkeypatch):
    monkeypatch.delenv(WORKERS_ENV, raising=False)
    monkeypatch.setattr(conftest.os, 'sched_getaffinity', lambda pid: {0, 1})
    monkeypatch.setattr(conftest, '_cpu_cgroup_roots', lambda: [])
    n, why = auto_workers()
    assert n == 0 and why.endswith('no CPU cgroup tree')


def test_with_one_ros_worker_no_offline_worker_joins_it():
    assert ros_workers(2) == 1 and joining_workers(2) == 0
    assert ros_workers(4) == 2 and joining_workers(4) == conftest.JOINING_WORKERS
