"""Many captures on Ray (issue #30); the code is in `freqbrdf.batch.runner`, split next."""

from freqbrdf.batch.runner import *  # noqa: F403
from freqbrdf.batch.runner import (  # noqa: F401
    _capture_inputs,
    _child_main,
    _in_fresh_process,
    _input_record,
    _up_to_date,
)
