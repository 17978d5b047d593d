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


@pytest.mark.parametrize("toml, key", [
    ("[pipeline]\nshutdown_timeout_s = inf", "pipeline.shutdown_timeout_s: inf is not a finite number"),
    ("[pipeline]\ninput_queue = 1000000000", "pipeline.input_queue: 1000000000 is not in 1..1024"),
    ("[pipeline]\nworkers = 1000", "pipeline.workers: 1000 is not in 1.."),
    ("[pipeline]\nworkers = 99999999999", "pipeline.workers: 99999999999 is larger than any setting"),
    ("[pipeline]\ntasks_per_worker = 1e9", "pipeline.tasks_per_worker: expected int"),
    ("[pipeline]\ndrain_timeout_s = 1e9", "pipeline.drain_timeout_s: 1000000000.0 is not in"),
    ("[camera]\nread_timeout_s = inf", "camera.read_timeout_s: inf is not a finite number"),
    ("[camera]\nread_timeout_s = 3600", "camera.read_timeout_s: 3600.0 is not in"),
    ("[health]\nstale_after_s = nan", "health.stale_after_s: nan is not a finite number"),
    ("[intrinsics]\nfx = nan", "intrinsics.fx: nan is not a finite number"),
    ("[intrinsics]\nfx = -5.0", "intrinsics.fx: expected a finite focal length in 1.76..176000 pixels, got -5.0"),
    ("[intrinsics]\nfx = 1e-300", "intrinsics.fx: expected a finite focal length in 1.76..176000 pixels"),
    ("[intrinsics]\nwidth = 100000\nheight = 100000", "intrinsics.width: image size 100000 x 100000: larger"),
    ("[intrinsics]\nwidth = 0", "intrinsics.width: expected a whole number of pixels >= 1, got 0"),
    ("[intrinsics]\nwidth = 5000\nheight = 5000", "intrinsics.width: image size 5000 x 5000"),  # every input's cap
    ("[intrinsics]\ncx = 1e6", "intrinsics.cx: expected a finite principal point near the image (-176..352)"),
])
def test_out_of_bounds_values_are_config_errors_naming_the_key(tmp_path, toml, key):
    path = tmp_path / "tofd.toml"
    path.write_text(toml + "\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert key in str(err.value)


def test_deeply_nested_toml_is_a_config_error(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ConfigError, match="nested too deeply"):
        load_config(path)
