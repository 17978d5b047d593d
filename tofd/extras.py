"""Which optional part of tofd (a pip extra) brings which third-party module: `pip install tofd` installs the
algorithm alone; the daemon, viewer, recordings, bags and batch processing come with extras (pyproject.toml)."""

from __future__ import annotations

EXTRA_MODULES: dict[str, str] = {
    "rerun": "service",
    "usb": "service",
    "mcap": "service",
    "mcap_protobuf": "service",
    "foxglove_schemas_protobuf": "service",
    "google.protobuf": "service",
    "zstandard": "service",
    "prometheus_client": "service",
    "matplotlib": "service",
    "tqdm": "service",
    "dask": "batch",
    "distributed": "batch",
    "pyarrow": "batch",
    "fsspec": "batch",
    "rosbags": "rosbag",
}
"""Top-level module (as imported) -> the extra that installs it."""


def missing_extra(exc: ImportError) -> str | None:
    """The extra whose module `exc` failed to import, or None (not an optional module's absence)."""
    name = exc.name or ""
    for module, extra in EXTRA_MODULES.items():
        if name == module or name.startswith(module + "."):
            return extra
    return None


def install_hint(extra: str) -> str:
    return f"needs the '{extra}' extra: pip install 'tofd[{extra}]'"
