"""The one catalogue of candidate effects, for poses (`diagnose`) and trajectory runs (`diagnose_runs`): one module
per effect, where all that the diagnosis knows of it lives.

Each effect is a small model extension declared once (`Effect`): its parameter names, typical sizes and units, where
it can be seen (`seen_in`: poses at rest, runs, or both), which parameters are physical only at or above 0, a hook
`apply(robot, v, orders) -> robot` that is the identity at `v = 0`, and hooks for what is special about it in the
workflows (its variants' names, derived values, the values a run fit reports, a staged run fit). Per-joint effects
get `v` of shape (joints, p) (one row per joint; the pose workflow frees one row at a time), global ones (p,). The
model's own effects (`jaxrobot.effects.EFFECTS`) are candidates through their declared parameters (`ModelEffect`,
one per parameter); an effect of identification alone is one subclass of `Effect` in its module here, placed in
`CATALOGUE`. `catalogue(robot, marker, "poses")` and `catalogue(robot, marker, "runs")` are what each workflow draws
from it.
"""

from ._catalogue import CATALOGUE as CATALOGUE
from ._catalogue import Layout as Layout
from ._catalogue import catalogue as catalogue
from ._effect import Effect as Effect
from ._payload import payload_robot as payload_robot
from ._pose import RIPPLE_SLOTS as RIPPLE_SLOTS
from ._pose import with_ripple_slots as with_ripple_slots
