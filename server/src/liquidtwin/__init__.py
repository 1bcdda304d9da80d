"""liquidtwin: a live, differentiable twin of the liquid a robot pours, scoops or carries."""

from .sim import *  # noqa: F401,F403 - the SPNets core is the package's public face
from .sim import __all__ as _sim_all

__version__ = "0.1.0"
__all__ = list(_sim_all) + ["__version__"]
