"""DynoPlan: a hybrid hierarchical controller over options with learned dynamics.

The library follows the paper's parts (Angelov, Hristov, Ramamoorthy, "DynoPlan:
Combining Motion Planning and Deep Neural Network based Controllers for Safe HRL",
RLDM 2019):

- :mod:`dynoplan.options`   -- ``Option`` (policy, initiation, termination, dynamics)
- :mod:`dynoplan.models`    -- dynamics models, goal heuristics, safety regions (Eq. 5)
- :mod:`dynoplan.planning`  -- ``OptionPlanner``, the n-step MPC choice (Eq. 1)
- :mod:`dynoplan.control`   -- ``Controller``: plan, run, monitor, plan again
- :mod:`dynoplan.envs`      -- Gymnasium environments (random walk, gear assembly)
- :mod:`dynoplan.experiments` -- wiring of the parts into the paper's experiments
"""

from dynoplan.errors import DynoplanError

__version__ = "0.1.0"

__all__ = ["DynoplanError", "__version__"]
