"""Pipeline results to viewers, each in its own process (process.py, with no viewer SDK): Rerun (rerun_sink.py: the
entity tree and blueprint, the per-frame logger, file and viewer sinks) and the Foxglove publisher's shared pixel
conventions. Importing the package loads no viewer SDK: its Rerun names load on first use."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tofd.service.viewer.blueprint import build_blueprint as build_blueprint
    from tofd.service.viewer.logger import RerunLogger as RerunLogger
    from tofd.service.viewer.process import ViewerError as ViewerError
    from tofd.service.viewer.targets import RerunTarget as RerunTarget

_LAZY = {"RerunLogger": "tofd.service.viewer.logger", "RerunTarget": "tofd.service.viewer.targets",
         "ViewerError": "tofd.service.viewer.process", "build_blueprint": "tofd.service.viewer.blueprint"}

__all__ = ["RerunLogger", "RerunTarget", "ViewerError", "build_blueprint"]


def __getattr__(name: str) -> Any:
    """The Rerun names, imported when first asked for (they load the Rerun SDK)."""
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_LAZY[name]), name)
