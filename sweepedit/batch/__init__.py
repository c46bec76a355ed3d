"""`sweepedit batch`: fit whole collections of shapes, on Ray or in this process.

inputs  what INPUT... names (files, folders, globs, lists) and each shape's output name
jobs    one shape, run in a worker: load, fit, metrics, mesh -> a JobOutcome
engine  Ray (local or a cluster) and the in-process engine
summary summary.csv and which shapes a rerun skips
runner  the driver loop: slots, outputs, kills, progress, Ctrl-C
report  the table of means and medians and the contact sheet (shared with bench)
"""

from sweepedit.batch.inputs import ShapeInput, expand_inputs
from sweepedit.batch.jobs import JobOutcome, JobSpec
from sweepedit.batch.runner import BatchOptions, BatchReport, run_batch

__all__ = ["BatchOptions", "BatchReport", "JobOutcome", "JobSpec", "ShapeInput",
           "expand_inputs", "run_batch"]
