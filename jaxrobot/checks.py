"""Argument checks for the packages built on `jaxrobot`: `check_public(globals())` at the end of a
package's `__init__` checks the shapes and dtypes of every public function's arguments from its
jaxtyping annotations (`jaxrobot._checks`); `require_elastic` rejects rigid joints where the
elastic model is integrated; `deprecated_aliases` keeps a moved public name at its old path for one release."""

from ._checks import check_public as check_public
from ._checks import checked as checked
from ._deprecation import deprecated_aliases as deprecated_aliases
from ._elasticity import require_elastic as require_elastic
