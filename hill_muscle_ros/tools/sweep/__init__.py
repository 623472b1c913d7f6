"""``hill-muscle sweep``: simulate one protocol over many muscle or limb parameter sets.

A sweep spec (YAML) names a protocol, optional base parameters (or a limb
plant), the parameters to vary and the instants to sample. The parameter sets
are cut into chunks; each chunk is simulated at once by a batch engine
(:class:`~hill_muscle_ros.model.muscle.batch.MuscleBatch` for the muscle,
:class:`~hill_muscle_ros.model.limb.LimbBatch` for a limb) on a Dask
worker, either of a local cluster started for the sweep or of an existing one
given by its scheduler address. The result is a tidy Parquet table: one row
per parameter set and sample time.

Spec keys::

    protocol: II                 # I, II or a protocol YAML (relative to the spec)
    params: muscle.yaml          # optional base parameters file (same rules)
    rate_hz: 1000                # optional step rate [Hz] (else the file's, else 1000)
    sample_times_s: [1.0, 6.0]   # [s] instants to sample, multiples of 1 / rate_hz
    vary:                        # a grid of every combination ...
      f_iso_max_n: [30, 45, 60]                      # listed values
      k_se_n_per_m: {low: 5e3, high: 2e4, n: 4, log: true}   # or a range of n
    samples: 64                  # ... or, with ranges only (no n), a Latin
    seed: 0                      # hypercube of this many sets (seed default 0)

A limb sweep gives ``plant`` (a limb plant file, as ``hill-muscle simulate
--plant`` reads) instead of ``params``, a limb protocol, and names the plant's
parameters in ``vary`` with the plant file's dotted names: ``joint.<field>``
(a :class:`~hill_muscle_ros.model.limb.JointParams` field) and
``<muscle>.<field>`` (a muscle's ``moment_arm_m``, ``reference_angle_rad`` or
any :class:`~hill_muscle_ros.model.params.MuscleParams` field)::

    plant: knee.yaml
    protocol: protocols/knee_extension.yaml
    sample_times_s: [1.0, 2.0]
    vary:
      quadriceps.f_iso_max_n: [1000.0, 1500.0]
      joint.stiffness_n_m_per_rad: {low: 10.0, high: 20.0, n: 3}

Its rows hold ``theta_rad`` and one ``<muscle>_force_n`` column per muscle
(the names of ``hill-muscle simulate --plant``'s CSV) instead of ``force_n``.

The modules: :mod:`.spec` reads and validates the spec, :mod:`.simulation` is
what a task computes, :mod:`.execution` runs the tasks (here or on Dask),
:mod:`.output` writes the Parquet table, and :mod:`.command` is the
subcommand's parser and glue.

Dask, SciPy and pyarrow are imported only by the functions that need them:
the rest of the package runs without them. This package has no rclpy.
"""
from .command import EXIT_INTERRUPTED, add_parser, cmd_sweep
from .execution import (CLIENT_GONE, HEARTBEAT_FAILED, QUIET_HEARTBEAT_PLUGIN, ClientGoneFilter,
                        HeartbeatOnCloseFilter, Progress, SweepResult, quiet_heartbeat_on_close,
                        run_local, run_on_client, run_sweep)
from .output import check_out, force_columns, to_table, write_parquet
from .simulation import (MAX_AUTO_CHUNK, MAX_AUTO_LIMB_CHUNK, chunk_ranges, run_chunk,
                         run_limb_chunk, simulate_forces)
from .spec import SweepError, SweepSpec, load_spec, parse_spec

__all__ = [
    'CLIENT_GONE', 'EXIT_INTERRUPTED', 'HEARTBEAT_FAILED', 'MAX_AUTO_CHUNK',
    'MAX_AUTO_LIMB_CHUNK', 'QUIET_HEARTBEAT_PLUGIN', 'ClientGoneFilter', 'HeartbeatOnCloseFilter',
    'Progress', 'SweepError', 'SweepResult', 'SweepSpec', 'add_parser', 'check_out',
    'chunk_ranges', 'cmd_sweep', 'force_columns', 'load_spec', 'parse_spec',
    'quiet_heartbeat_on_close', 'run_chunk', 'run_limb_chunk', 'run_local', 'run_on_client',
    'run_sweep', 'simulate_forces', 'to_table', 'write_parquet',
]
