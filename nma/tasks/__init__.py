from . import digital_mnist, rotation, shape_matching, spec, translation  # noqa: F401  (registers the tasks)
from .base import Task  # noqa: F401
