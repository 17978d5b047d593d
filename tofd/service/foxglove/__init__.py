"""The live stream over the Foxglove WebSocket protocol (foxglove-sdk), beside the Rerun sink: topics.py names
what is published, publisher.py publishes a frame, spec.py reads --foxglove."""
