"""Argument checks of the public functions, from their jaxtyping annotations.

`checked(fn)` reads `fn`'s annotations (`Float[Array, "*b n"]`, `Robot`, `bool`) and, before `fn`
runs, checks every argument's type, dtype kind and shape, raising an error that names the
argument, the expected shape and what was found, e.g. `q: expected shape (..., n) with n = 6
joints of this robot, found (5,)`. Only shapes and dtypes are read, so the checks run at trace
time under `jit`, `vmap` and `grad` and cost nothing inside compiled code. Lists and tuples of
numbers are turned into arrays.

Dimension names: with a robot argument, `n` (and `6`, the joint count of annotations written for six joints) is
its joint count and `24` or `4*n` the state size `4 n`; other numbers are fixed sizes; other names
(and `n` without a robot) must agree between the arguments of one call; `*b` (any name after
`*`) and `...` are batch dimensions, which must broadcast against each other.
"""

from __future__ import annotations

import functools
import inspect
import re
from collections.abc import Callable

import numpy as np

_ARRAY = re.compile(r"\b(Float|Real|Int|Bool|Shaped|Num|Integer)\[\s*Array\s*,\s*['\"]([^'\"]*)['\"]\s*\]")
_KINDS = {"Float": "fiu", "Real": "fiu", "Num": "fiuc", "Int": "iu", "Integer": "iu", "Bool": "b", "Shaped": None}
_KIND_NAMES = {"fiu": "real numbers", "fiuc": "numbers", "iu": "integers", "b": "booleans"}


class _Spec:
    """What one annotated argument may be."""

    def __init__(self, annotation: str):
        m = None if re.search(r"\b(tuple|list|dict|Callable)\[", annotation) else _ARRAY.search(annotation)
        self.kind = _KINDS[m.group(1)] if m else None
        self.dims = m.group(2).split() if m else None
        self.optional = "None" in annotation
        self.scalar_bool = bool(re.search(r"(^|\|)\s*bool\s*($|\|)", annotation))
        self.robot = bool(re.fullmatch(r"\s*(jr\.|jaxrobot\.)?Robot\s*(\|\s*None\s*)?", annotation))
        self.flag = annotation.strip() == "bool"
        # classes besides the array (`Float[Array, "K n"] | Poses`): an instance of one is not checked here
        self.classes = set(re.findall(r"\b([A-Z]\w*)\b", _ARRAY.sub("", annotation))) - {"None", "Robot"}

    @property
    def used(self) -> bool:
        return self.dims is not None or self.robot or self.flag


def _size(token: str, n: int | None):
    """The size a core dimension token stands for: an int, `None` (a name to bind) or a string."""
    if token == "n" or (token == "6" and n is not None):
        return n  # without a robot argument, `n` is a name like any other
    if token in ("24", "4*n", "4n") and n is not None:
        return 4 * n
    return int(token) if token.isdigit() else None


def _shown(dims: list[str], n: int | None) -> str:
    names = {"6": "n", "24": "4n", "4*n": "4n"} if n is not None else {}
    out = ["..." if d.startswith("*") or d == "..." else names.get(d, d) for d in dims if d != "_"]
    return "(" + ", ".join(out) + ("," if len(out) == 1 else "") + ")"


def _shape_error(name: str, dims: list[str], n: int | None, found) -> ValueError:
    joints = n is not None and any(d in ("n", "6", "24", "4*n") for d in dims)
    note = f" with n = {n} joints of this robot" if joints else ""
    return ValueError(f"{name}: expected shape {_shown(dims, n)}{note}, found {tuple(found)}")


def checked(fn: Callable) -> Callable:
    """`fn` with its arguments checked against its annotations (module docstring)."""
    from ._robot import Robot

    sig = inspect.signature(fn)
    specs = {k: _Spec(p.annotation) for k, p in sig.parameters.items() if isinstance(p.annotation, str)}
    specs = {k: s for k, s in specs.items() if s.used}
    if not specs:
        return fn

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        bound = sig.bind(*args, **kwargs)
        given = bound.arguments
        n = None
        for name, spec in specs.items():
            if spec.robot and name in given and (given[name] is not None or not spec.optional):
                if not isinstance(given[name], Robot):
                    raise TypeError(f"{name}: expected a jaxrobot.Robot (e.g. jr.racer7()), found "
                                    f"{type(given[name]).__name__}")
                n = given[name].a.shape[-1]
        sizes: dict[str, tuple[int, str]] = {}
        batches: list[tuple[str, tuple]] = []
        for name, spec in specs.items():
            if name not in given or spec.robot:
                continue
            v = given[name]
            if spec.flag:
                if not isinstance(v, (bool, np.bool_)):
                    raise TypeError(f"{name}: expected True or False, found {v!r}")
                continue
            if v is None and spec.optional:
                continue
            if type(v).__name__ in spec.classes:
                continue
            if spec.scalar_bool and isinstance(v, (bool, np.bool_)):
                continue
            if isinstance(v, (list, tuple)):
                try:
                    v = given[name] = np.asarray(v, dtype=float if spec.kind != "b" else bool)
                except (TypeError, ValueError):
                    raise TypeError(f"{name}: expected an array of {_KIND_NAMES.get(spec.kind, 'numbers')} of shape "
                                    f"{_shown(spec.dims, n)}, found a {type(v).__name__} that is not one") from None
            if isinstance(v, (int, float)) and not isinstance(v, bool) and spec.kind != "b":
                shape, kind = (), "f"
            elif hasattr(v, "shape") and hasattr(v, "dtype"):
                shape, kind = tuple(v.shape), np.dtype(v.dtype).kind
            else:
                raise TypeError(f"{name}: expected an array of shape {_shown(spec.dims, n)}"
                                f"{' or a bool' if spec.scalar_bool else ''}, found {type(v).__name__} {v!r:.40}")
            if spec.kind is not None and kind not in spec.kind:
                raise TypeError(f"{name}: expected {_KIND_NAMES[spec.kind]}"
                                f"{' (or a bool)' if spec.scalar_bool else ''}, found dtype {np.dtype(v.dtype)}")
            dims = [d for d in spec.dims if not d.startswith("#")] or spec.dims
            var = [i for i, d in enumerate(dims) if d.startswith("*") or d == "..."]
            core = dims[var[0] + 1:] if var else dims
            if (len(shape) < len(core)) if var else (len(shape) != len(core)):
                raise _shape_error(name, spec.dims, n, shape)
            tail = shape[len(shape) - len(core):]
            for d, s in zip(core, tail):
                if d == "_":
                    continue
                want = _size(d, n)
                if isinstance(want, int) and s != want:
                    raise _shape_error(name, spec.dims, n, shape)
                if want is None:
                    if d in sizes and sizes[d][0] != s:
                        raise ValueError(f"{name}: dimension {d} is {s}, but {sizes[d][1]} has {d} = {sizes[d][0]} "
                                         f"(expected shape {_shown(spec.dims, n)})")
                    sizes.setdefault(d, (s, name))
            if var:
                batches.append((name, shape[: len(shape) - len(core)]))
        try:
            np.broadcast_shapes(*(b for _, b in batches))
        except ValueError:
            raise ValueError("batch dimensions do not broadcast: "
                             + ", ".join(f"{k} {b}" for k, b in batches)) from None
        return fn(*bound.args, **bound.kwargs)

    return wrapper


def check_public(namespace: dict) -> None:
    """Replace every public function in `namespace` (a package's `globals()`) by `checked(fn)`."""
    for name, obj in list(namespace.items()):
        if not name.startswith("_") and callable(obj) and not inspect.isclass(obj):
            try:
                namespace[name] = checked(obj)
            except (TypeError, ValueError):  # no signature (builtins, some jitted callables)
                continue
