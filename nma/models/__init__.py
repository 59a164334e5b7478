from .mlp import Encoder  # noqa: F401  (registers the models)
