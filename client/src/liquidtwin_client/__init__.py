"""liquidtwin's robot-side client library and ``liquidtwin-client`` command line."""

from .recording import ChannelSummary, RecordingError, RecordingSummary, summarize_recording

__all__ = ["ChannelSummary", "RecordingError", "RecordingSummary", "summarize_recording"]
