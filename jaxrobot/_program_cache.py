"""Exported programs on disk, so that a new process skips tracing and lowering of the large ones.

JAX's persistent compilation cache (`_compilation_cache`) stores compiled executables, but a new
process must still trace a function and lower it to StableHLO before it can look the executable
up; for the OCP solve and the simulations that costs more than the cache saves. `cached_program`
wraps a function like `jax.jit` (or `eqx.filter_jit` with `filter=True`) and, on a call with
concrete arguments, stores its `jax.export` serialization in `cache_dir() / "programs"`; a later
process deserializes it and calls it through `jax.jit`, whose executable then comes from the
compilation cache.

A program is found again only under the same key: the hash of the sources and data of the
packages `jaxrobot`, `planning` and `identification` as the process first reads them (a code
change invalidates every program; each version of the sources has its own subfolder), the jax
and jaxlib versions, the backend, x64, the function and its code, the tree structure and the
shapes, dtypes and weak types of the traced arguments, and the values of the static ones. Static
values and tree structures enter the key by their `repr`; one whose `repr` does not show its value
(an object address, an elision) makes the call run uncached, and so does a closure (its captured
values would be baked into the program). A program therefore reads no constant from outside its
arguments except the packages' own code and data: wrap functions of these packages only. Calls
under a transformation (`jit`, `vmap`, `grad`: tracers among the arguments) run the plain jitted
function.

The switch is the compilation cache's: `JAXROBOT_CACHE_DIR=off` turns both off.

`preparing` makes programs ready ahead of their use: within its block, in the calling thread, a call of a
`cached_program` loads (or exports and compiles) its program and returns zeros of its result's shapes without
running it, so that a second thread can make the programs of a later step ready while the first computes. Threads
that need the same program wait for the one making it ready.

`compile_timer` measures the time a block spends making programs ready (tracing, lowering, XLA compilation
or its fetch from the compilation cache, and the loading and storing of exported programs here), so that
one call gives both its compile and its run time.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import inspect
import os
import pickle
import threading
import time
from collections.abc import Callable, Iterator
from importlib.util import find_spec
from pathlib import Path

import equinox as eqx
import jax
import jax.export
import jax.monitoring
import jax.numpy as jnp
import jaxlib
import numpy as np

from ._compilation_cache import cache_dir
from ._jax_internals import weakly_typed

_PACKAGES = ("jaxrobot", "planning", "identification")
_UNSHOWN = (" at 0x", "...", "object>")
_ANY_CUSTOM_CALL = (jax.export.DisabledSafetyCheck.custom_call("ALL"),)
_NOT_EXPORTABLE = object()  # stored as a pickled `None`: later processes do not try again
_PROGRAM_EVENT = "/jaxrobot/program_cache/ready"
"""The time span of loading or exporting a program (`compile_timer`)."""
_COMPILE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration",
                   "/jax/core/compile/backend_compile_duration", _PROGRAM_EVENT)
"""The JAX monitoring events whose time spans `compile_timer` counts (the backend compile's includes a fetch from the
persistent compilation cache)."""


_LOCAL = threading.local()
_KEY_LOCKS: dict[str, threading.Lock] = {}
_KEY_LOCKS_LOCK = threading.Lock()


@contextlib.contextmanager
def preparing() -> Iterator[bool]:
    """Within the block, in the calling thread, a call of a `cached_program` makes its program ready for the calls
    of the same key (module docstring) and returns zeros of its result's shapes instead of running it; other
    computations in the block run as usual, and so does a call inside a traced function (its zeros would enter the
    traced program). For making the programs of a later step ready beside other work, from arguments of the shapes
    (and static values) that step will pass. Yields whether programs are kept (False where the cache is off: there
    is nothing to make ready, and the block may be skipped)."""
    before = getattr(_LOCAL, "preparing", False)
    _LOCAL.preparing = True
    try:
        yield program_dir() is not None
    finally:
        _LOCAL.preparing = before


def _is_preparing() -> bool:
    """In a `preparing` block of this thread, outside any trace (where `jnp` makes tracers, not values)."""
    return getattr(_LOCAL, "preparing", False) and not isinstance(jnp.zeros(()), jax.core.Tracer)


def _zeros(shapes):
    """Zeros (numpy) of the `jax.ShapeDtypeStruct` leaves of `shapes`, other leaves kept."""
    return jax.tree.map(lambda s: np.zeros(s.shape, s.dtype) if isinstance(s, jax.ShapeDtypeStruct) else s, shapes)


def _key_lock(key: str) -> threading.Lock:
    with _KEY_LOCKS_LOCK:
        return _KEY_LOCKS.setdefault(key, threading.Lock())


class CompileTime:
    """The time [s] that the block of a `compile_timer` spent making programs ready."""

    def __init__(self) -> None:
        self._spans: list[tuple[float, float]] = []
        self._thread = threading.get_ident()

    def _add(self, event: str, start: float, end: float, **_) -> None:
        if event in _COMPILE_EVENTS and threading.get_ident() == self._thread:
            self._spans.append((start, end))

    @property
    def seconds(self) -> float:
        """The length of the union of the compile events' time spans (nested events counted once)."""
        total, reach = 0.0, -float("inf")
        for start, end in sorted(self._spans):
            total += max(end - max(start, reach), 0.0)
            reach = max(reach, end)
        return total


@contextlib.contextmanager
def compile_timer() -> Iterator[CompileTime]:
    """A block's time spent making programs ready: tracing, lowering, XLA compilation (or its fetch from the
    persistent compilation cache) and the loading and exporting of `cached_program`s, from JAX's monitoring
    events of the calling thread (JAX compiles in the thread that calls); the union of their time spans, so
    `elapsed - seconds` is the block's run time."""
    timer = CompileTime()
    jax.monitoring.register_event_time_span_listener(timer._add)
    try:
        yield timer
    finally:
        jax.monitoring.unregister_event_time_span_listener(timer._add)


def program_dir() -> Path | None:
    """The folder of the exported programs of these sources (`cache_dir() / "programs" / hash`);
    `None` when switched off."""
    folder = cache_dir()
    return None if folder is None else folder / "programs" / _source_hash()


@functools.cache
def _source_hash() -> str:
    digest = hashlib.sha256()
    for name in _PACKAGES:
        spec = find_spec(name)
        if spec is None or spec.origin is None:
            continue
        root = Path(spec.origin).parent
        for file in sorted(root.rglob("*")):
            if file.is_file() and "__pycache__" not in file.parts:
                digest.update(f"{name}/{file.relative_to(root)}".encode())
                digest.update(file.read_bytes())
    return digest.hexdigest()[:16]


class _Uncacheable(Exception):
    """An argument whose value cannot be told from its `repr`."""


def _shown(obj) -> str:
    text = repr(obj)
    if any(mark in text for mark in _UNSHOWN):
        raise _Uncacheable(text)
    return text


def cached_program(fn: Callable | None = None, *, static_argnames: tuple[str, ...] = (), filter: bool = False):
    """`jax.jit(fn, static_argnames=...)` (or `eqx.filter_jit(fn)` with `filter=True`: arrays traced,
    all other leaves static) whose exported program is kept on disk between processes (module
    docstring). Results are those of the jitted function."""
    if fn is None:
        return functools.partial(cached_program, static_argnames=static_argnames, filter=filter)
    jitted = eqx.filter_jit(fn) if filter else jax.jit(fn, static_argnames=static_argnames)
    sig = inspect.signature(fn)
    loaded: dict[str, tuple[Callable, object]] = {}  # key -> (compiled program, output tree)

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        folder = program_dir()
        if folder is None:
            return uncached(*args, **kwargs)
        bound = sig.bind(*args, **kwargs)
        bound.apply_defaults()
        static = {k: v for k, v in bound.arguments.items() if k in static_argnames}
        leaves, tree = jax.tree_util.tree_flatten({k: v for k, v in bound.arguments.items() if k not in static})
        traced = [eqx.is_array(x) or not filter for x in leaves]
        dynamic = [x for x, t in zip(leaves, traced, strict=True) if t]
        if fn.__closure__ or any(isinstance(x, jax.core.Tracer) for x in dynamic):
            return uncached(*args, **kwargs)
        try:
            key = _key(fn, tree, static, [None if t else x for x, t in zip(leaves, traced, strict=True)], dynamic)
        except _Uncacheable:
            return uncached(*args, **kwargs)
        if key not in loaded:
            start = time.time()  # the clock of JAX's own time spans
            with _key_lock(key):  # one thread makes the program ready, another one waits for it
                if key not in loaded:
                    loaded[key] = _ready(folder, key, fn, sig, tree, static, leaves, traced, dynamic)
            jax.monitoring.record_event_time_span(_PROGRAM_EVENT, start, time.time(), fun_name=fn.__name__)
        if loaded[key] is _NOT_EXPORTABLE:
            return uncached(*args, **kwargs)
        call, out_tree = loaded[key]
        if _is_preparing():
            return jax.tree_util.tree_unflatten(out_tree, _zeros(call.out_info))
        return jax.tree_util.tree_unflatten(out_tree, call(*dynamic))

    def uncached(*args, **kwargs):
        if _is_preparing():
            return _zeros(eqx.filter_eval_shape(jitted, *args, **kwargs))
        return jitted(*args, **kwargs)

    wrapper.jitted = jitted
    return wrapper


def _ready(folder: Path, key: str, fn, sig, tree, static, leaves, traced, dynamic) -> tuple[Callable, object] | object:
    """The compiled program of `key` and its output structure: its exported program (loaded, or exported now)
    compiled (its executable from the compilation cache where it holds one); `_NOT_EXPORTABLE` for a function that
    cannot be exported."""
    program = _load(folder, key, fn.__name__) or _export(folder, key, fn, sig, tree, static, leaves, traced, dynamic)
    if program is _NOT_EXPORTABLE:
        return program
    call, out_tree = program
    return call.lower(*dynamic).compile(), out_tree


def _key(fn, tree, static: dict, static_leaves: list, dynamic: list) -> str:
    avals = [str(jax.typeof(x)) for x in dynamic]
    parts = [_source_hash(), jax.__version__, jaxlib.__version__, jax.default_backend(),
             str(jax.config.jax_enable_x64), f"{fn.__module__}.{fn.__qualname__}",
             _code_digest(fn.__code__), _shown(tree),
             _shown(sorted(static.items())), _shown(static_leaves), ",".join(avals)]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:32]


def _code_digest(code) -> str:
    """A digest of a code object that, unlike `marshal`, is the same in every process."""
    consts = [_code_digest(c) if inspect.iscode(c) else repr(sorted(map(repr, c)) if isinstance(c, frozenset) else c)
              for c in code.co_consts]
    text = repr((code.co_code, code.co_names, code.co_varnames, code.co_freevars, code.co_cellvars, consts))
    return hashlib.sha256(text.encode()).hexdigest()


def _callable(exported, weak: list[bool], name: str) -> Callable:
    """The exported program under `jit`, named `name` (compile logs, profiles); outputs weakly typed
    where the traced function's were (a deserialized program forgets weak types)."""

    def call(*args):
        return [weakly_typed(x) if w else x for x, w in zip(exported.call(*args), weak)]

    call.__name__ = call.__qualname__ = name
    return jax.jit(call)


def _export(folder: Path, key: str, fn, sig, tree, static, leaves, traced, dynamic) -> tuple[Callable, object]:
    out_trees = []

    def flat(*values):
        values = iter(values)
        arguments = jax.tree_util.tree_unflatten(tree, [next(values) if t else x for x, t in zip(leaves, traced)])
        bound = inspect.BoundArguments(sig, {**arguments, **static})
        out, out_tree = jax.tree_util.tree_flatten(fn(*bound.args, **bound.kwargs))
        out_trees.append(out_tree)
        return out

    # the key holds the jax and jaxlib versions: custom calls (LAPACK) need no compatibility guarantee
    try:
        exported = jax.export.export(jax.jit(flat), disabled_checks=_ANY_CUSTOM_CALL)(*dynamic)
        blob = bytes(exported.serialize())
        weak = [a.weak_type for a in exported.out_avals]
    except (ValueError, NotImplementedError, ImportError):  # e.g. host callbacks; no `flatbuffers`
        _write(folder, f"{key}.program", pickle.dumps(None))
        return _NOT_EXPORTABLE
    out_tree = out_trees[0]
    # the output structure is stored as a tree of integers (a pickled PyTreeDef does not compare equal)
    skeleton = jax.tree_util.tree_unflatten(out_tree, list(range(out_tree.num_leaves)))
    _write(folder, f"{key}.program", pickle.dumps((blob, skeleton, weak)))
    # the program as a later process reads it, so that every process runs the same
    return _callable(jax.export.deserialize(bytearray(blob)), weak, fn.__name__), out_tree


def _write(folder: Path, name: str, data: bytes) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{name}.{os.getpid()}.tmp"
        tmp.write_bytes(data)
        os.replace(tmp, folder / name)
    except OSError:  # a read-only cache: run without storing
        pass


def _load(folder: Path, key: str, name: str) -> tuple[Callable, object] | object | None:
    try:
        stored = pickle.loads((folder / f"{key}.program").read_bytes())
        if stored is None:
            return _NOT_EXPORTABLE
        blob, skeleton, weak = stored
        exported = jax.export.deserialize(bytearray(blob))
    except (OSError, pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, ImportError):
        return None
    return _callable(exported, weak, name), jax.tree_util.tree_structure(skeleton)
