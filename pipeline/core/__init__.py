"""The ground floor's contracts every stage and method is written against: options declared as
data (:mod:`.options`) and the stage protocol (:mod:`.stage`).

Importing this package imports no numpy, so the command line's parser can use it.
"""

from .options import Options, OptionSpec, option, switch
from .stage import Outcome, Stage

__all__ = ["Options", "OptionSpec", "option", "switch", "Stage", "Outcome"]
