"""G-code: the text of jobs, and slicers' files translated into Robox jobs."""

from robox.gcode.files import JobFile, job_file, roboxise_file, strip_file
from robox.gcode.text import code_part, looks_like_gcode, prepare_job, split_lines, words
from robox.gcode.translate import (
    Detected,
    Options,
    Summary,
    detect,
    head_kind,
    translate,
)

__all__ = ["Detected", "JobFile", "Options", "Summary", "code_part", "detect", "head_kind",
           "job_file", "looks_like_gcode", "prepare_job", "roboxise_file", "split_lines",
           "strip_file", "translate", "words"]
