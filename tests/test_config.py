import pytest

from tofd.config import DEFAULT_CONFIG_PATH, Config, ConfigError, config_from_dict, load_config


def test_bundled_config_loads_and_matches_defaults():
    assert load_config(DEFAULT_CONFIG_PATH) == Config()


def test_unknown_key_is_named():
    with pytest.raises(ConfigError, match="camera.sereal"):
        config_from_dict({"camera": {"sereal": "1234"}})


def test_wrong_type_is_named():
    with pytest.raises(ConfigError, match="camera.int_time_code"):
        config_from_dict({"camera": {"int_time_code": "fast"}})


def test_int_widens_to_float():
    cfg = config_from_dict({"segmentation": {"range_percentile": 25}})
    assert cfg.segmentation.range_percentile == 25.0


def test_missing_file_is_clear(tmp_path):
    with pytest.raises(ConfigError, match="cannot read config"):
        load_config(tmp_path / "nope.toml")
