"""The live/replay pipeline: capture thread, feature worker processes over shared memory, detection, sinks."""

from tofd.pipeline.core import Pipeline, PipelineError
from tofd.pipeline.ledger import DropLedger
from tofd.pipeline.results import FrameResult, ResultsWriter

__all__ = ["DropLedger", "FrameResult", "Pipeline", "PipelineError", "ResultsWriter"]
