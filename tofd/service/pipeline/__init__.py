"""The live/replay pipeline: capture thread, feature worker processes over shared memory, detection, sinks."""

from tofd.service.pipeline.core import Pipeline, PipelineError, maps_read
from tofd.service.pipeline.ledger import DropLedger
from tofd.service.pipeline.results import FrameResult, ResultsWriter

__all__ = ["DropLedger", "FrameResult", "Pipeline", "PipelineError", "ResultsWriter", "maps_read"]
