"""One configuration per network architecture (``edofproj.net_config``): the registry and the
configuration classes name the same networks, each option is checked against what it declares,
``--set`` switches and refuses keys per architecture, and the single flat ``net`` section of older
files -- the configuration each shipped checkpoint records -- still loads, converted with a one-line
note, into the shipped ``config.yaml`` (which needs no conversion), the configuration that rebuilds
the network its checkpoint holds."""

from __future__ import annotations

import warnings

import pytest

from edofproj.builtin_runs import BUILTIN_RUNS, PREFIX, builtin_run_dir
from edofproj.compensation.registry import NETWORKS, build_network
from edofproj.config import (
    Config,
    ConfigError,
    dump_config,
    from_dict,
    load_config,
    safe_load_yaml,
    to_dict,
    unread_doe_keys,
)
from edofproj.errors import ConfigConversionWarning
from edofproj.net_config import (
    FLAT_NET_KEYS,
    NET_CONFIGS,
    RENAMED,
    MultirateConfig,
    OnlineProDebConfig,
    UNetConfig,
    convert_flat_net,
    declared_options,
    option_names,
)
from edofproj.runs import load_run
from edofproj.runs.checkpoint import load_checkpoint
from edofproj.runs.directory import saved_config


def test_the_registry_and_the_configuration_classes_name_the_same_architectures():
    assert list(NETWORKS) == list(NET_CONFIGS)
    for name, cls in NET_CONFIGS.items():
        assert cls.architecture == name and NETWORKS[name].config is cls
    small = {"widths": [4, 8]}
    for cls in (UNetConfig, MultirateConfig):
        assert isinstance(build_network(cls(**small)), NETWORKS[cls.architecture].network)
    assert isinstance(build_network(OnlineProDebConfig()), NETWORKS["onlineprodeb"].network)


@pytest.mark.parametrize("cls", list(NET_CONFIGS.values()), ids=list(NET_CONFIGS))
def test_every_option_declares_its_meaning_and_its_default_is_allowed(cls):
    cls().validate()
    for field, spec in declared_options(cls):
        assert spec.meaning and spec.rule(), field.name
        assert spec.unit == "px" or not field.name.endswith("_px"), field.name  # a unit in the name is declared


def _just_outside(spec, default):
    """A value its declaration refuses, next to the allowed range (or not a choice, or too short a list,
    or not true/false)."""
    if spec.boolean:
        return "yes"
    if spec.choices:
        return "?not-a-choice?"
    if spec.min_items:
        return [1] * (spec.min_items - 1)
    r = spec.range
    if r.low is not None:
        return r.low if r.low_open else (r.low - 1 if spec.integer else r.low - 1e-3)
    return r.high if r.high_open else r.high + 1


@pytest.mark.parametrize("cls", list(NET_CONFIGS.values()), ids=list(NET_CONFIGS))
def test_a_value_outside_the_declared_range_is_one_config_error_naming_the_key(cls):
    for field, spec in declared_options(cls):
        bad = _just_outside(spec, getattr(cls(), field.name))
        with pytest.raises(ConfigError, match=rf"^net\.{field.name}="):
            cls(**{field.name: bad}).validate()
    if cls is UNetConfig:  # a value the declared range allows besides it: 0 = no pre-filter
        UNetConfig(prefilter_bins=0).validate()
        with pytest.raises(ConfigError, match="goes with net.prefilter_bins=0"):
            UNetConfig(prefilter_bins=8, linear_base="ensemble").validate()


def test_set_switches_the_architecture_keeping_the_shared_options():
    cfg = load_config("cpu", ["net.leaky_slope=0.1", "net.linear_radius=15", "net.architecture=onlineprodeb"])
    assert isinstance(cfg.net, OnlineProDebConfig)
    assert to_dict(cfg.net) == {
        "architecture": "onlineprodeb",
        "leaky_slope": 0.1,
        "linear_nsr": 0.01,
        "linear_radius": 15,
        "surface_input": False,
    }
    multirate = load_config("cpu", ["net.architecture=multirate", "net.block_px=2"]).net
    assert isinstance(multirate, MultirateConfig)
    assert multirate.widths == load_config("cpu").net.widths and multirate.block_px == 2 and multirate.filter_bins == 48
    back = load_config("cpu", ["net.architecture=onlineprodeb", "net.architecture=unet"]).net
    assert isinstance(back, UNetConfig) and back.widths == UNetConfig().widths  # unet's own defaults again


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["net.architecture=onlineprodeb", "net.widths=[4,8]"], r"'net\.widths': the onlineprodeb network has no such"),
        (["net.architecture=multirate", "net.space_to_depth=4"], r"the multirate network calls it 'net\.block_px'"),
        (["net.block_px=4"], r"'net\.block_px': the unet network has no such option"),
        (["net.widht=[4,8]"], r"did you mean 'net\.widths'\?"),
        (["net.architecture=unett"], r"net\.architecture='unett' is not one of unet, onlineprodeb, multirate"),
    ],
)
def test_set_refuses_a_key_the_chosen_architecture_does_not_have(overrides, message):
    with pytest.raises(ConfigError, match=message):
        load_config("cpu", overrides)


@pytest.mark.parametrize("architecture", list(NET_CONFIGS))
def test_a_saved_config_reads_back_unchanged_without_a_note(tmp_path, architecture):
    cfg = load_config("cpu", [f"net.architecture={architecture}"])
    path = tmp_path / "config.yaml"
    path.write_text(dump_config(cfg), encoding="utf-8")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = load_config(str(path))
    assert to_dict(again) == to_dict(cfg) and type(again.net) is type(cfg.net)


def test_a_file_refuses_a_key_that_is_neither_an_option_nor_of_the_flat_section(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("net:\n  architecture: onlineprodeb\n  widhts: [4, 8]\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"'net\.widhts': the onlineprodeb network has no such option"):
        load_config(str(path))


def test_a_flat_multirate_section_is_renamed_with_a_note(tmp_path):
    """The realtime preset as it was written before the split."""
    path = tmp_path / "realtime-old.yaml"
    path.write_text(
        "net:\n  architecture: multirate\n  widths: [8, 16]\n  space_to_depth: 4\n  prefilter_bins: 48\n"
        "  init_nsr: 0.01\n  linear_base: none\n",
        encoding="utf-8",
    )
    with pytest.warns(ConfigConversionWarning) as caught:
        cfg = load_config(str(path))
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    assert "renamed space_to_depth -> block_px, prefilter_bins -> filter_bins; dropped linear_base" in str(
        caught[0].message
    )
    assert isinstance(cfg.net, MultirateConfig)
    assert (cfg.net.widths, cfg.net.block_px, cfg.net.filter_bins, cfg.net.init_nsr) == ([8, 16], 4, 48, 0.01)
    net = build_network(cfg.net)
    assert net.block == 4 and net.prefilter.gain.shape == (3, 48)


@pytest.mark.parametrize("name", list(BUILTIN_RUNS))
def test_every_shipped_run_loads_without_a_note(name):
    """A shipped ``config.yaml`` is in the current format: commands on a built-in run print no
    conversion note (a warning on every command would be noise a user cannot act on)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConfigConversionWarning)
        cfg = saved_config(PREFIX + name)
    flat = safe_load_yaml((builtin_run_dir(name) / "config.yaml").read_text(encoding="utf-8"))["net"]
    assert set(flat) - {"architecture"} <= set(option_names(type(cfg.net)))


def _read_keys(config: dict) -> dict:
    """``config`` without the classic elements' keys its DOE never reads (a learned DOE's shipped
    ``config.yaml`` holds the tuned ones, so that its evaluation scores the tuned rivals), and without a
    fixed DOE's ``doe.path``: a trained run loads its design from its own ``doe.npz`` (``load_run``), and the
    path it was trained from may name a built-in run that has been renamed since."""
    unread = set(unread_doe_keys(config["doe"]["kind"])) | ({"path"} if config["doe"]["kind"] == "file" else set())
    return {**config, "doe": {k: v for k, v in config["doe"].items() if k not in unread}}


@pytest.mark.parametrize("name", list(BUILTIN_RUNS))
def test_the_flat_section_a_shipped_run_was_trained_with_converts_to_its_config(name):
    """Each shipped checkpoint records the configuration it was trained with in the single flat
    format (the older files' case): converted, it keeps every value its network read, drops only
    the keys its network ignored with one note, and gives exactly the shipped ``config.yaml`` --
    so the shipped file scores as the trained network did -- and rebuilds the network whose weights
    the checkpoint holds (``load_run`` loads them strictly)."""
    recorded = load_checkpoint(builtin_run_dir(name) / "checkpoints" / "last.pt")["config"]
    flat = recorded["net"]
    shipped = to_dict(saved_config(PREFIX + name))
    if "space_to_depth" not in flat or "init_nsr" not in flat:  # trained in today's format: nothing to convert
        trained = from_dict(Config, recorded)
        assert _read_keys(to_dict(trained)) == _read_keys(shipped)
        run = load_run(PREFIX + name)  # the network of its last phase (refit_net where there is one)
        assert isinstance(run.net, NETWORKS[trained.network_at(run.step).architecture].network)
        return
    net, note = convert_flat_net(flat)
    assert note is not None and "net: a single flat section of an older edofproj" in note and "\n" not in note
    cls = NET_CONFIGS[flat["architecture"]]
    renamed = RENAMED.get(cls.architecture, {})
    for key, value in flat.items():
        if key in option_names(cls) or key == "architecture":
            assert net[key] == value, key
        elif key in renamed:
            assert net[renamed[key]] == value, key
        else:
            assert key in FLAT_NET_KEYS and key not in net, key
            assert f"dropped {key}" in note or f", {key}" in note
    assert _read_keys(to_dict(from_dict(Config, {**recorded, "net": net}))) == _read_keys(shipped)
    run = load_run(PREFIX + name)
    assert isinstance(run.net, NETWORKS[cls.architecture].network)
