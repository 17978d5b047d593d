"""Recordings of frames: the MCAP record layout, the crash-safe writer, the replay source."""
