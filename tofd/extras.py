"""Which optional part of tofd (a pip extra, pyproject.toml) each command and third-party module belongs to:
`pip install tofd` installs the algorithm alone; the daemon, viewer, recordings, bags, the lab and batch
processing come with extras."""

from __future__ import annotations

MODULE_EXTRAS: dict[str, str | None] = {
    "rerun": "service",
    "usb": "service",
    "mcap": "service",
    "mcap_protobuf": "service",
    "foxglove_schemas_protobuf": "service",
    "google": "service",
    "zstandard": "service",
    "prometheus_client": "service",
    "waitress": "service",
    "av": "service",
    "foxglove": "service",
    "isal": "service",
    "msgpack": "service",
    "dask": "batch",
    "distributed": "batch",
    "pyarrow": "batch",
    "rosbags": "rosbag",
    "lz4": "rosbag",
    "tqdm": None,  # in several extras: the command's
    "matplotlib": None,
    "fsspec": None,
}
"""Top-level module (as imported) -> the extra that installs it (None: several do; the command's extra)."""

COMMAND_EXTRAS: dict[str, str] = {
    "run": "service", "replay": "service", "record": "service", "convert": "service", "devices": "service",
    "info": "service", "export": "service",
    "import": "rosbag", "batch": "batch", "train": "lab", "evaluate": "lab", "dataset": "lab", "experiment": "lab",
}
"""`tofd` command -> the extra it needs."""


def missing_extra(exc: ImportError, command: str) -> str | None:
    """The extra to install for `command` that failed with `exc`, or None when `exc` is not the absence of an
    optional module (a bug, reported as such)."""
    top = (exc.name or "").split(".")[0]
    if top not in MODULE_EXTRAS:
        return None
    return MODULE_EXTRAS[top] or COMMAND_EXTRAS.get(command, "all")


def install_hint(extra: str) -> str:
    return f"needs the '{extra}' extra: pip install 'tofd[{extra}]'"
