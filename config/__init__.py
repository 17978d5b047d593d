"""Default configuration files of tofd, installed as the package `tofd.defaults` (see pyproject.toml)."""
