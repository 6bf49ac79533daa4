"""Visualisation: contact sheets (PNG), rerun recordings (.rrd) and matplotlib plots.

Owns pictures of artefacts; computes nothing the pipeline depends on.
"""

from ._sheet import (
    colorize_depth as colorize_depth,
    colorize_labels as colorize_labels,
    contact_sheet as contact_sheet,
    save_contact_sheet as save_contact_sheet,
)
from ._studio import log_studio as log_studio, studio_contact_sheet as studio_contact_sheet
from ._track import log_tracking as log_tracking, overlay_frames as overlay_frames, write_overlay_video as write_overlay_video
