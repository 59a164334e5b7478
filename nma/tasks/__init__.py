"""The tasks: what the network is asked and how it is scored (the protocol: nma.tasks.base).

Importing this package declares every built-in task with its schema (nma.tasks.schemas) and imports
no task's code: `nma.registry.TASKS.get(name)` imports it on first use.
"""

from . import schemas  # noqa: F401  (declares the built-in tasks)
