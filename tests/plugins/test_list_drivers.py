"""``scatterlab devices --list-drivers``: every driver with its kind and where it comes
from; refused plugins named with what to do, the other drivers listed regardless."""

from __future__ import annotations

import pytest

from instrument.bench.driver_registry import driver_registry
from instrument.cli import main
from tests.plugins.fake_dists import GOOD_MODULE, make_dist, unique


def _rows(out: str) -> dict[str, str]:
    return {line.split()[0]: line for line in out.splitlines() if line.strip()}


def test_lists_builtin_and_plugin_drivers_with_kind_and_origin(capsys):
    from importlib.metadata import version

    assert main(["devices", "--list-drivers"]) == 0
    rows = _rows(capsys.readouterr().out)
    apt = rows["thorlabs_apt"].split()
    assert apt[1:3] == ["motion_axis", "scatterlab"] and apt[3] == version("scatterlab")
    assert "built-in" in rows["thorlabs_apt"] and "simapt://" in rows["thorlabs_apt"]
    assert rows["pm100usb"].split()[1] == "power_meter"
    plugin = rows["example_meter"].split()
    assert plugin[1:5] == ["power_meter", "scatterlab-example-meter", "1.0.0", "plugin"]
    assert "simem1://" in rows["example_meter"]


@pytest.fixture
def site(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    driver_registry.cache_clear()
    yield tmp_path
    monkeypatch.undo()
    driver_registry.cache_clear()


def test_a_broken_plugin_is_named_with_what_to_do_and_the_others_still_listed(site, capsys):
    broken, wrong, good = unique("broken"), unique("wrong"), unique("good")
    make_dist(site, "broken-dist", "0.1", {"broken_meter": f"{broken}:DRIVER"},
              {broken: "raise RuntimeError('firmware table missing')\n"})
    make_dist(site, "wrong-dist", "0.2", {"wrong_meter": f"{wrong}:DRIVER"},
              {wrong: "from instrument.bench.driver_registry import DriverEntry\n"
                      "DRIVER = DriverEntry('power_meter', 'drivers.base:Camera')\n"})
    make_dist(site, "good-dist", "1.0", {"good_meter": f"{good}:DRIVER"}, {good: GOOD_MODULE})
    assert main(["devices", "--list-drivers"]) == 1
    out = capsys.readouterr().out
    listed, _, refused = out.partition("refused")
    assert "good_meter" in listed and "good-dist" in listed and "thorlabs_apt" in listed
    assert "broken_meter" not in listed and "wrong_meter" not in listed
    assert "driver 'broken_meter'" in refused and "broken-dist 0.1" in refused
    assert "firmware table missing" in refused and "uninstall broken-dist" in refused
    assert "driver 'wrong_meter'" in refused and "wrong-dist 0.2" in refused
    assert "not a subclass of drivers.base.PowerMeter" in refused
