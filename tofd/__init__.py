"""tofd: scale-invariant range features and nose detection for time-of-flight cameras."""

__version__ = "0.1.0"
