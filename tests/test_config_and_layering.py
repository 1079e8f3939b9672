"""The typed configuration, and the layering rule: the core imports no ROS, files, CLI or plots."""

import subprocess
import sys

import pytest

from ltmap_cli.config import Config, dump_config, load_config, set_dotted
from ltmap_cli.errors import ConfigError


def test_defaults_are_the_spec_values():
    c = Config()
    assert c.map.resolution == 0.05
    assert (c.map.layers.tick, c.map.layers.st_rise_s, c.map.layers.st_fall_s) == (0.2, 15.0, 1.0)
    assert (c.map.layers.st_forget_s, c.map.layers.lt_fall_s, c.map.layers.static_margin_cells) == (60.0, 3.0, 1)
    assert (c.map.projection.z_min, c.map.projection.z_max) == (0.05, 1.5)
    assert (c.map.projection.occupied_thresh, c.map.projection.free_thresh) == (0.65, 0.196)
    assert c.map.sensor.hit_logodds == pytest.approx(0.847, abs=1e-3)
    assert c.map.sensor.miss_logodds == pytest.approx(-0.405, abs=1e-3)
    assert (c.map.sensor.clamp_min_logodds, c.map.sensor.clamp_max_logodds) == (-2.0, 3.5)
    assert c.map.sensor.depth_max_range == 8.0 and c.map.sensor.ground_tolerance == 0.05


def test_yaml_round_trip_and_errors(tmp_path):
    c = Config()
    set_dotted(c, "map.layers.tick", 0.1)
    set_dotted(c, "map.resolution", 0.1)
    p = tmp_path / "config.yaml"
    p.write_text(dump_config(c))
    back = load_config(p)
    assert back == c
    p.write_text("map:\n  layers:\n    tik: 0.1\n")
    with pytest.raises(ConfigError, match="unknown config key map.layers.tik"):
        load_config(p)
    p.write_text("map:\n  resolution: fine\n")
    with pytest.raises(ConfigError, match="map.resolution must be a number"):
        load_config(p)
    p.write_text("map:\n  projection:\n    z_min: 2.0\n")
    with pytest.raises(ConfigError, match="z_max"):
        load_config(p)
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.yaml")


def test_core_imports_no_ros_files_cli_or_plotting():
    code = (
        "import sys\n"
        "import ltmap_cli.core.layers, ltmap_cli.core.projection, ltmap_cli.core.sensors, ltmap_cli.core.grid\n"
        "bad = [m for m in ('rosbags', 'mcap', 'click', 'matplotlib', 'open3d', 'ltmap_cli.io', "
        "'ltmap_cli.cli', 'ltmap_cli.pipeline.replay', 'ltmap_cli.viz.plots') if m in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_help_does_not_import_heavy_modules():
    code = (
        "import sys\nfrom click.testing import CliRunner\nfrom ltmap_cli.cli import cli\n"
        "r = CliRunner().invoke(cli, ['--help'])\nassert r.exit_code == 0, r.output\n"
        "print(','.join(m for m in ('numba', 'open3d', 'rosbags', 'mcap', 'matplotlib') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


@pytest.mark.parametrize("key", ["replay.map_period", "replay.robot_radius", "map.layers.tick", "map.resolution"])
@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_non_finite_parameters_are_refused_by_name(key, value):
    cfg = Config()
    set_dotted(cfg, key, value)
    with pytest.raises(ConfigError, match=key.replace(".", r"\.") + " must be a finite number"):
        cfg.validate()
