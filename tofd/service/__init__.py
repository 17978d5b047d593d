"""The camera service: the threaded pipeline, the Rerun viewer sink, health and metrics, the daemon wiring."""
