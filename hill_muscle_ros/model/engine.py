"""Which build of the model's kernels runs, and the numba machinery that compiles them.

The kernels (:mod:`.muscle.kernels`, :mod:`.muscle.batch_kernels`,
:mod:`.limb.kernels`) are plain functions, run as they are or compiled by numba
from the *same* code. :func:`kernels` is the one place that chooses between the
two builds; this module also builds the compiled one, and is the only place
that imports numba, lazily, so importing the package never loads it.

Choice: the environment variable :data:`ENV_VAR` (``HILL_MUSCLE_ENGINE``)
takes ``auto`` (the default: compiled if numba can be imported), ``compiled``
(numba required) or ``python`` (the plain functions everywhere: for debugging,
or to rule the compiled code out). :func:`choice` reads it on every call, so a
process may change it; a facade's ``build=`` argument overrides it.

Compiling: :func:`compile_functions` compiles a module's plain functions,
each from its own code object with the names it calls rebound to their
compiled versions, and caches them on numba's disk cache. numba's cache
notices a change of the compiled function's own file but not of the modules
it inlines, so the cache names carry a digest of those modules
(:func:`source_digest`): an edited curve compiles anew. Where no cache
directory is writable (numba raises then), :func:`njit_cached` compiles in
memory and warns once (:class:`CacheUnavailableWarning`).
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import types
import warnings
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

#: Environment variable choosing the engine: one of :data:`VALUES`.
ENV_VAR = 'HILL_MUSCLE_ENGINE'
#: Accepted values of :data:`ENV_VAR`; the first is the default.
VALUES = ('auto', 'compiled', 'python')
#: What :func:`choice` returns.
COMPILED, PYTHON = 'compiled', 'python'

#: The OpenMP runtime's setting that :func:`import_numba` defaults to ``PASSIVE``.
OMP_WAIT_POLICY = 'OMP_WAIT_POLICY'

#: Hex digits of :func:`source_digest` in cache names: enough that two
#: versions of the digested files practically never share one.
CACHE_DIGEST_CHARS = 12

#: numba's options for helpers compiled by :func:`compile_functions` unless
#: told otherwise. error_model='numpy': a division gives inf/nan instead of
#: raising, so loops have no exception paths and vectorise (no division in
#: the model is by zero for valid parameters). inline='always': helpers are
#: inlined in numba's IR, so LLVM sees one loop body.
HELPER_OPTIONS = {'error_model': 'numpy', 'inline': 'always'}
#: numba's options for every function :func:`compile_functions` compiles, under
#: its own. ``_nrt=False`` leaves numba's runtime out: no reference counting of
#: the arrays a compiled function passes to another. The kernels allocate
#: nothing (flat arrays in, scalars out), and the Python caller holds every
#: array for the call. With the runtime, its reference counts were most of a
#: limb step: NRT_incref and NRT_decref took 24 % of a profile of the knee
#: (perf, the kernels themselves 4 %), and leaving it out took the idle
#: knee's step from 2.0 to 0.44 us (benchmarks/bench_limb_compiled.py).
NO_RUNTIME = {'_nrt': False}

#: True once :class:`CacheUnavailableWarning` was issued in this process.
_warned_cache = False
#: numba's event broadcast while a dispatcher compiles (or loads from its cache).
COMPILE_EVENT = 'numba:compile'
#: Times numba's compilations once numba is imported (:func:`compile_seconds`).
_compile_timer = None


class CacheUnavailableWarning(RuntimeWarning):
    """numba found no writable cache directory: compiled code is kept in memory only,
    so every process compiles anew."""


def requested() -> str:
    """The engine asked for in :data:`ENV_VAR`: one of :data:`VALUES`.

    :raises ValueError: if the variable holds anything else
    """
    value = os.environ.get(ENV_VAR, VALUES[0]).strip().lower() or VALUES[0]
    if value not in VALUES:
        raise ValueError(f'`{ENV_VAR}` must be one of {", ".join(VALUES)}, '
                         f'got {os.environ[ENV_VAR]!r}')
    return value


def numba_available() -> bool:
    """True if numba can be imported (checked without importing it)."""
    try:
        return importlib.util.find_spec('numba') is not None
    except (ImportError, ValueError):
        return False


def choice() -> str:
    """The engine the model's loops take now: :data:`COMPILED` or :data:`PYTHON`.

    ``auto`` gives :data:`COMPILED` when numba can be imported. Cheap: numba
    is looked for, not imported.

    :raises ValueError: if :data:`ENV_VAR` holds an unknown value
    :raises ImportError: if it asks for ``compiled`` and numba cannot be imported
    """
    value = requested()
    if value == PYTHON:
        return PYTHON
    if numba_available():
        return COMPILED
    if value == COMPILED:
        raise ImportError(f'`{ENV_VAR}` is {COMPILED!r}, but numba cannot be imported')
    return PYTHON


def kernels(module: types.ModuleType, build: str | None = None) -> object:
    """The build of a kernel module to run: the one place the engine is chosen.

    :param module: a module of plain kernel functions with a ``compiled()``
        that returns their numba build (e.g. :mod:`hill_muscle_ros.model.muscle.kernels`)
    :param build: :data:`COMPILED` or :data:`PYTHON` to ask for one, or None
        for :func:`choice` (``HILL_MUSCLE_ENGINE``)
    :return: ``module.compiled()`` for :data:`COMPILED`, else ``module``
        itself: the very same functions, run as plain Python
    :raises ValueError: if ``build`` or :data:`ENV_VAR` holds an unknown value
    :raises ImportError: if it asks for ``compiled`` and numba cannot be imported
    """
    if build is None:
        build = choice()
    elif build not in (COMPILED, PYTHON):
        raise ValueError(f'`build` must be {COMPILED!r}, {PYTHON!r} or None, got {build!r}')
    return module.compiled() if build == COMPILED else module


def import_numba() -> types.ModuleType:
    """Import numba (lazily: never at package import) and return it.

    numba's default threading layer here is GNU OpenMP, whose idle threads
    spin while they wait: on cores busy with other processes that made 2
    threads 5x slower than 1 (measured at K = 10,000: 4.9-5.5 ms a step
    against 0.8-1.1 ms; with passive waiting 0.58-0.71 ms against 0.52-0.58).
    The runtime reads ``OMP_WAIT_POLICY`` when numba first loads it, so it is
    defaulted to ``PASSIVE`` here; a value the user set wins.

    :raises ImportError: if numba cannot be imported
    """
    global _compile_timer
    os.environ.setdefault(OMP_WAIT_POLICY, 'PASSIVE')
    import numba
    if _compile_timer is None:
        from numba.core import event
        _compile_timer = event.TimingListener()
        event.register(COMPILE_EVENT, _compile_timer)
    return numba


def compile_seconds() -> float:
    """[s] wall time this process has spent in numba's compiler so far.

    Summed over the outermost compilations (a kernel's callees compile within
    it); loading from the disk cache is not compiling and is not counted
    (numba broadcasts no compile event for it). 0 before :func:`import_numba`.
    The test suite prints it at its end, against the 60 s it may spend.
    """
    timer = _compile_timer
    return timer.duration if timer is not None and timer.done else 0.0


def source_digest(modules: Iterable[types.ModuleType]) -> str:
    """Hex digest of the source files of ``modules``, for compiled functions' cache names.

    :param modules: the modules whose code the compiled functions inline
    :return: the first :data:`CACHE_DIGEST_CHARS` hex digits of their SHA-256
    """
    sources = b''.join(Path(m.__file__).read_bytes() for m in modules)
    return hashlib.sha256(sources).hexdigest()[:CACHE_DIGEST_CHARS]


def _cache_places(fn: Callable) -> str:
    """The directories numba tries for ``fn``'s cache, for the warning."""
    numba = import_numba()
    places = [str(Path(fn.__code__.co_filename).parent / '__pycache__')]
    if numba.config.CACHE_DIR:
        places.insert(0, f'{numba.config.CACHE_DIR} (NUMBA_CACHE_DIR)')
    return ', '.join(places)


def njit_cached(fn: Callable, signature=None, **options) -> Callable:
    """``numba.njit(signature, cache=True, **options)(fn)``, in memory if it cannot cache.

    numba raises when no cache directory is writable (``NUMBA_CACHE_DIR`` and
    the source's ``__pycache__`` both unusable); the function is then
    compiled without the disk cache, and a :class:`CacheUnavailableWarning`
    naming the directories is issued once per process.

    :param fn: the plain Python function
    :param signature: numba signature; with one, compiled (or loaded) now
    :param options: further options of ``numba.njit``
    """
    global _warned_cache
    numba = import_numba()
    args = () if signature is None else (signature,)
    try:
        return numba.njit(*args, cache=True, **options)(fn)
    except RuntimeError as exc:
        if 'cannot cache' not in str(exc):
            raise
        if not _warned_cache:
            _warned_cache = True
            warnings.warn(f'numba cannot write its cache to {_cache_places(fn)}: the '
                          'compiled model is kept in memory only, so every process '
                          'compiles it anew (set NUMBA_CACHE_DIR to a writable directory)',
                          CacheUnavailableWarning, stacklevel=2)
        return numba.njit(*args, cache=False, **options)(fn)


def compile_functions(scope: Mapping[str, object], names: Sequence[str], *,
                      foreign: Sequence[Callable] = (),
                      digest_of: Sequence[types.ModuleType] = (),
                      signatures: Mapping[str, Callable] | None = None,
                      options: Mapping[str, Mapping] | None = None,
                      bind: Mapping[str, Callable] | None = None) -> types.SimpleNamespace:
    """Compile plain functions of a module with numba, calling each other compiled.

    Each function named in ``names`` is rebuilt from its own code object over
    a copy of ``scope`` in which the names it calls are bound to their
    compiled versions, so the plain functions stay plain (Python runs them
    unchanged) and numba compiles the same code. Cache names carry
    :func:`source_digest` of ``digest_of``.

    :param scope: the module's globals (``globals()``), copied, never changed
    :param names: functions of ``scope`` to compile, callees before callers
    :param foreign: functions of other modules the named ones call, compiled
        first as helpers over their own globals (e.g. the curves, which read
        their module's constants); their cache follows their own file, so
        list their modules in ``digest_of`` too
    :param digest_of: modules inlined into the named functions whose edits
        numba's cache would not notice
    :param signatures: name -> ``f(numba)`` returning the numba signature:
        those functions are compiled (or loaded from the cache) now, once
    :param options: name -> options of ``numba.njit`` replacing
        :data:`HELPER_OPTIONS` for that function (e.g. ``parallel=True``)
    :param bind: extra name -> ``f(numba)`` bindings in the scope (e.g.
        ``{'prange': lambda nb: nb.prange}``)
    :return: ``numba`` and each named function, compiled, as attributes
    :raises ImportError: if numba cannot be imported
    """
    numba = import_numba()
    signatures = signatures or {}
    options = options or {}
    # This module is digested too: numba's cache does not key on the options.
    digest = source_digest(tuple(digest_of) + (sys.modules[__name__],))
    compiled = dict(scope)
    for name, make in (bind or {}).items():
        compiled[name] = make(numba)
    for fn in foreign:
        compiled[fn.__name__] = njit_cached(fn, **HELPER_OPTIONS, **NO_RUNTIME)
    for name in names:
        fn = scope[name]
        # Same code, but the names it calls resolve to the compiled versions.
        rebound = types.FunctionType(fn.__code__, compiled, fn.__name__, fn.__defaults__,
                                     fn.__closure__)
        rebound.__qualname__ = f'{fn.__qualname__}_{digest}'   # the cache file's name
        rebound.__doc__ = fn.__doc__
        signature = signatures[name](numba) if name in signatures else None
        compiled[name] = njit_cached(rebound, signature,
                                     **{**options.get(name, HELPER_OPTIONS), **NO_RUNTIME})
    return types.SimpleNamespace(numba=numba, **{n: compiled[n] for n in names})
